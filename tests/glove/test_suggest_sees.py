"""`htdata layouts suggest` names what it saw and what it could not see (issue 43, item 4): the glove's direction
(value.convention), the parts of the grid no recording pressed, and strips cut along the finger only."""

from __future__ import annotations

import json

import numpy as np
import pytest

from htdata.cli import main
from htdata.glove.activity import CellActivity, seen_direction
from htdata.glove.layouts import load_layout


@pytest.fixture(scope="module")
def sample_clips():
    from htdata.synthetic.rawglove import corpus_clips

    return corpus_clips(0)[1]


def _save(tmp_path, name: str, rows: np.ndarray):
    path = tmp_path / f"{name}.npy"
    np.save(path, np.asarray(rows, np.float32))
    return str(path)


def _boxes(layout) -> list[tuple[int, int, int, int]]:
    return sorted((b.rows[0], b.rows[1], b.cols[0], b.cols[1]) for b in layout.blocks)


def test_suggest_writes_inverted_for_a_glove_whose_counts_fall_with_pressure(tmp_path, sample_clips, capsys):
    """The same presses recorded by a glove whose counts fall (1023 - raw): value.convention "inverted" and the
    blocks of the direct glove."""
    direct = [_save(tmp_path, f"direct_{k}", c.counts["right"]) for k, c in enumerate(sample_clips)]
    inverted = [_save(tmp_path, f"inverted_{k}", 1023.0 - c.counts["right"].astype(np.float32))
                for k, c in enumerate(sample_clips)]
    assert main(["layouts", "suggest", *direct, str(tmp_path / "direct.json"), "--hand", "right"]) == 0
    assert main(["layouts", "suggest", *inverted, str(tmp_path / "inverted.json"), "--hand", "right"]) == 0
    printed = capsys.readouterr().out
    a, b = load_layout(tmp_path / "direct.json"), load_layout(tmp_path / "inverted.json")
    assert a.value["convention"] == "direct" and b.value["convention"] == "inverted"
    assert _boxes(a) == _boxes(b) and len(a.blocks) >= 9
    assert "value.convention inverted as the recordings show" in printed and "GUESS" not in printed
    assert "as the recordings show" in json.loads((tmp_path / "inverted.json").read_text())["notes"]


def test_the_direction_is_a_guess_said_so_when_the_recordings_do_not_tell(tmp_path, capsys):
    """A patch that rises and one that falls as much: either could be the presses; suggest says it guessed, and a
    stated --convention is written as stated."""
    rng = np.random.default_rng(1)
    x = 550 + rng.uniform(-20, 20, (1, 16, 16)) + rng.normal(0, 0.5, (600, 16, 16))
    press = 80.0 * (np.arange(600) % 200 // 16 == 6)[:, None, None]     # three half-second presses
    x[:, 0:4, 0:4] += press
    x[:, 8:12, 8:12] -= press
    acts = CellActivity((16, 16))
    acts.add(x.astype(np.float32))
    seen = seen_direction([acts], None)
    assert seen.inverted is None and seen.falls_as_direct == seen.falls_as_inverted == 16
    rec = _save(tmp_path, "rec", x)
    assert main(["layouts", "suggest", rec, str(tmp_path / "guess.json"), "--hand", "left"]) == 0
    out = capsys.readouterr().out
    assert "WARNING: value.convention direct is a GUESS, CHECK IT" in out
    assert "GUESS" in load_layout(tmp_path / "guess.json").notes
    assert main(["layouts", "suggest", rec, str(tmp_path / "stated.json"), "--hand", "left",
                 "--convention", "inverted"]) == 0
    assert load_layout(tmp_path / "stated.json").value["convention"] == "inverted"
    assert "as stated (--convention" in capsys.readouterr().out


# in how many of five pour clips each cell of the real right glove's ring strip moved (rows 4-11, cols 17-31 of its
# grid: the palm's edge columns, the strip's 4 rows 6-9 between unsensed rows): the strip's second pair of rows
# moves less, and the cut where the blocks narrow used to split the strip lengthwise into two 2-row strips
RING_STRIP_SUPPORT = np.array([
    [5, 4, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], [5, 5, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
    [5, 5, 4, 5, 5, 4, 2, 4, 4, 5, 3, 5, 4, 4, 1], [5, 5, 5, 4, 5, 3, 3, 5, 2, 5, 3, 5, 3, 4, 1],
    [5, 4, 4, 4, 5, 3, 1, 5, 1, 5, 3, 3, 4, 3, 1], [4, 4, 4, 3, 5, 3, 2, 5, 0, 5, 3, 5, 2, 3, 1],
    [5, 5, 1, 1, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0], [5, 5, 2, 3, 5, 5, 5, 5, 3, 5, 2, 4, 3, 5, 5]])


def test_a_strip_is_cut_across_into_places_never_lengthwise():
    from htdata.glove.layoutsuggest import suggested_boxes

    support = np.zeros((12, 20), np.int64)
    support[2:10, 2:17] = RING_STRIP_SUPPORT
    support[2:10, 0:2] = 5                                 # the palm beside it
    strip = [b for b in suggested_boxes(support, 5) if b[2] >= 4]
    # every block of the strip spans its four rows (4-7); the strip's 13 columns cut across into three places
    assert [(b[0], b[1]) for b in strip] == [(4, 7)] * 3
    assert [b[2] for b in strip] == [4, 8, 13] and strip[-1][3] == 16


def test_join_lengthwise_joins_thin_blocks_side_by_side_only_where_nothing_else_lies():
    from htdata.glove.blockcuts import join_lengthwise

    # two 2-row halves of a 4x12 strip, the lower one cut in two: one strip
    assert join_lengthwise([(0, 1, 0, 11), (2, 3, 0, 5), (2, 3, 7, 11)]) == [(0, 3, 0, 11)]
    # a thin column beside a block whose joined box would cover a third block: left alone
    boxes = [(0, 9, 10, 11), (0, 3, 6, 9), (5, 9, 4, 7)]
    assert join_lengthwise(boxes) == sorted(boxes)
    # wide blocks side by side are not a strip cut lengthwise
    assert join_lengthwise([(0, 3, 0, 11), (4, 7, 0, 11)]) == [(0, 3, 0, 11), (4, 7, 0, 11)]


def _little_finger_never_pressed(tmp_path, clips) -> list[str]:
    """The sample clips' right hand with the little finger's strip (rows 0-3, cols 19-30) at rest all along."""
    rng = np.random.default_rng(0)
    recs = []
    for k, clip in enumerate(clips):
        x = clip.counts["right"].astype(np.float32)
        rest = x[np.argmin(x.mean(axis=(1, 2))), 0:4, 19:31]
        x[:, 0:4, 19:31] = rest + rng.normal(0, 0.5, (len(x), 4, 12))
        recs.append(_save(tmp_path, f"rec_{k}", x))
    return recs


def test_suggest_names_the_part_of_the_glove_no_recording_pressed(tmp_path, sample_clips, capsys):
    """Recordings that never press the little finger's strip: no block lies there, and the summary, the printed
    lines and the notes name that region."""
    recs = _little_finger_never_pressed(tmp_path, sample_clips)
    out = tmp_path / "part.json"
    assert main(["layouts", "suggest", *recs, str(out), "--hand", "right"]) == 0
    printed = capsys.readouterr().out
    layout = load_layout(out)
    assert not layout.live_mask[0:4, 19:31].any()
    regions = [r for r in printed.splitlines() if r.startswith("not seen:")]
    assert len(regions) == 1 and "no block covers" in regions[0]
    named = np.zeros(layout.grid, bool)
    for r0, r1, c0, c1 in ((int(a), int(b), int(c), int(d)) for a, b, c, d in
                           __import__("re").findall(r"rows (\d+)-(\d+), cols (\d+)-(\d+)", regions[0])):
        named[r0:r1 + 1, c0:c1 + 1] = True
    # the strip inside the blocks' outline (the blocks reach column 28 here) is named whole, and no block is
    outline = max(b.cols[1] for b in layout.blocks)
    assert outline >= 26 and named[0:4, 19:outline + 1].all() and not (named & layout.live_mask).any()
    assert "no block covers" in layout.notes


def test_the_places_of_a_full_hand_without_a_block_are_named():
    from htdata.glove.layouts import load_canonical
    from htdata.glove.layoutsuggest import unseen_text

    text = unseen_text([(0, 3, 19, 30)], ["palm", "thumb.distal", "index.distal"], 2)
    assert "rows 0-3, cols 19-30" in text and "6 of the 18 places of a full hand have a block" in text
    missing = text.split("none for ")[1].split(" (")[0].split(", ")
    assert len(missing) == 12 and "thumb.proximal" in missing and not any(p.startswith("palm") for p in missing)
    assert "places of a full hand" not in unseen_text([], sorted(load_canonical().places), 2)


def _not_pressed(printed: str) -> set[str]:
    lines = [r for r in printed.splitlines() if r.startswith("not pressed:")]
    assert len(lines) <= 1
    return set(__import__("re").findall(r"(\w+) \(\w+\.\w+, rows", lines[0])) if lines else set()


def test_check_against_names_the_blocks_no_recording_pressed(tmp_path, sample_clips, capsys):
    from htdata.synthetic.rawglove import glove_layout

    layout = tmp_path / "sample_right.json"
    layout.write_text(json.dumps(glove_layout("right").to_dict()))
    whole = [_save(tmp_path, f"all_{k}", c.counts["right"]) for k, c in enumerate(sample_clips)]
    main(["layouts", "check", str(layout), "--against", *whole])
    idle = _not_pressed(capsys.readouterr().out)           # the sample clips never press the ring finger's tip
    assert len(idle) <= 2 and not any(b.startswith("little") for b in idle)
    main(["layouts", "check", str(layout), "--against", *_little_finger_never_pressed(tmp_path, sample_clips)])
    assert _not_pressed(capsys.readouterr().out) == idle | {"little_proximal", "little_middle", "little_distal"}
