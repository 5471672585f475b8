"""Moving cells and suggested blocks on the REAL raw-count glove recordings (../shared/real_glove, README targets).

The development clips of a two-hand 32x32 knitted glove sit beside the
repository (`../shared/real_glove`: clips/clip_N.npz raw counts, its layout
files, the README's measures and targets); without that folder these tests
skip. The measures are htdata/benchmarks/realglovecells.py's (also run as
`python -m htdata.benchmarks.realglovecells ../shared/real_glove`).
"""

from __future__ import annotations

import pytest

from htdata.benchmarks.realclips import load_real_glove
from htdata.benchmarks.realglovecells import crosstalk_rows, moving_cell_rows, suggest_glove_rows, suggest_rows
from tests.factories.realglove import real_glove_dir


@pytest.fixture(scope="module")
def real():
    return load_real_glove(real_glove_dir())


def test_check_against_flags_only_cells_that_really_move_on_long_and_short_clips(real):
    rows = moving_cell_rows(*real)
    assert {(r["hand"], r["clips"].split()[0]) for r in rows} == {(h, c) for h in ("left", "right")
                                                                  for c in ("all", "short")}
    for r in rows:
        where = f"{r['hand']} hand, {r['clips']} clips"
        assert r["under_quiet"] == 0, f"{where}: a cell ranging < 10 counts was reported"
        if r["flagged"]:
            assert r["precision"] >= 0.90, f"{where}: flag precision {r['precision']:.3f}"
        if r["crosstalk"]:
            assert r["crosstalk_precision"] >= 0.90, f"{where}: cross-talk precision {r['crosstalk_precision']:.3f}"
    full = {r["hand"]: r for r in rows if r["clips"].startswith("all")}
    # the forgotten-sensor flags are there (column 31 and the cells around the thumb move on this glove), and the
    # cells that only fall beside a press are told apart from them
    assert full["left"]["flagged"] > 0 and full["right"]["flagged"] > 0
    assert full["left"]["crosstalk"] > 0


def test_suggest_cuts_the_connected_glove_into_blocks_that_match_its_live_cells(real):
    for r in suggest_rows(*real):
        where = f"{r['hand']} hand, {r['clips']} clips"
        # the README's measure on any set of clips: precision, recall of the live cells they press in >= 2 of them,
        # the direction seen, and where a part of the glove was never found, regions named
        assert r["precision"] >= 0.90 and r["recall_pressed"] >= 0.90, f"{where}: {r}"
        assert r["convention"] == "direct", where
        if r["recall"] < 0.90:
            assert r["uncovered_regions"] >= 1 and r["missed_named"] >= 0.5, f"{where}: {r}"
        if not r["clips"].startswith("all"):
            continue                      # the short clips alone press too little of the left hand to find it
        where = f"{r['hand']} hand: {r['blocks']} blocks {r['boxes']}"
        assert r["blocks"] >= 9, where
        assert r["precision"] >= 0.90, f"{where}: cell precision {r['precision']:.3f}"
        assert r["recall"] >= 0.90, f"{where}: cell recall {r['recall']:.3f}"


def test_health_crosstalk_flags_are_not_presses_along_a_strip_edge(real):
    """`stats --health` cross-talk on the real glove and each glove derived from it: >= 0.90 of the flags are true
    cross-talk (nothing pressed within the strip beside the line; issue 43 found 222 presses flagged)."""
    rows = crosstalk_rows(*real)
    assert {r["glove"] for r in rows} and all(r["hand"] in ("left", "right") for r in rows)
    for r in rows:
        if r["flagged"]:
            assert r["precision"] >= 0.90, f"{r['glove']}, {r['hand']} hand: {r['true']} of {r['flagged']} true"


def test_suggest_sees_each_derived_gloves_direction_and_finds_its_blocks(real):
    """The inverted glove (1023 - raw) gets value.convention inverted and the direct glove's blocks; every derived
    glove gets its own direction, and every one the README's block targets: the drifting, low-rest glove too (its
    common wander of +6 counts over every clip is taken out before a cell's movement is judged, issue 43)."""
    rows = {(r["glove"].split()[0], r["hand"]): r for r in suggest_glove_rows(*real)}
    assert all(r["convention_right"] for r in rows.values()), rows
    assert rows[("inverted", "left")]["convention"] == "inverted"
    assert ("low", "left") in rows and ("low", "right") in rows
    for (glove, hand), r in rows.items():
        assert r["blocks"] >= 9 and r["precision"] >= 0.90 and r["recall_pressed"] >= 0.90, (glove, hand, r)
