"""Live cells outside every block are a finding, never silently dropped (issue 19 item 2).

A 16x16 raw-count glove like a real knit one (rest ~550 counts with per-taxel
offsets, noise of 3 counts, contact +150..+400 counts, integer counts) is
recorded glove-only in the native format. Its first-draft layout maps the
index tip and the palm but forgets the thumb strip (rows 0-3, cols 10-15),
whose 24 cells are pressed during the recording. The ingest must name
exactly those cells (record, report, stderr), and not the resting cells
around them; listing them in `unused_cells` silences the finding.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from htdata.glove.activity import MOVING_K, MOVING_MIN_FULL_SCALE, WANDER_K, CellActivity, moving_cells, unmapped_moving
from htdata.glove.layouts import parse_layout
from htdata.store.manifest import load_episodes
from tests.factories import ingest_cli
from tests.factories.knitglove import GRID, NOISE, draft_layout, knit_counts, write_glove_only

THUMB = [(r, c) for r in range(0, 4) for c in range(10, 16)]       # live, forgotten by the draft layout


# --------------------------------------------------------------------------- the rule


def test_noise_estimate_is_the_white_noise_std_despite_offsets_drift_and_presses():
    rng = np.random.default_rng(1)
    x = 550 + rng.uniform(-30, 30, (1, 8, 8)) + rng.normal(0, 3.0, (3000, 8, 8))
    x += np.linspace(0, 20, 3000)[:, None, None]                      # slow drift
    x[1000:1030, 0, 0] += 300                                          # one press
    act = CellActivity((8, 8))
    for chunk in np.array_split(x, 7):                                 # streamed: same as one pass
        act.add(chunk)
    assert act.frames == 3000
    assert act.noise() == pytest.approx(3.0, rel=0.08)
    whole = CellActivity((8, 8))
    whole.add(x)
    assert np.allclose(whole.range, act.range) and whole.noise() == pytest.approx(act.noise())


def test_resting_noise_never_moves_a_press_does():
    rng = np.random.default_rng(2)
    x = 550 + rng.normal(0, 3.0, (18_000, 4, 4)).astype(np.float32)   # 10 minutes at 30 fps of pure noise
    x[5000:5010, 3, 3] += 100                                          # one brief, weak press
    act = CellActivity((4, 4))
    act.add(x)
    found = moving_cells(act, np.ones((4, 4), bool), None, step=1)
    assert found.cells.tolist() == [[3, 3]]
    assert found.threshold == pytest.approx(MOVING_K * act.noise() + WANDER_K * act.wander())
    assert 0 < act.wander() < 6.0          # white noise: block means (std 3 / 4) over 1125 blocks span ~4


def test_quantised_flicker_below_four_steps_stays_quiet_and_nan_cells_never_move():
    x = np.zeros((100, 2, 2), np.float32)
    x[::2, 0, 0] = 3                       # flickers 0 <-> 3 counts: noise ~2.7, range 3 < 4 steps... and < 12 x noise
    x[:, 0, 1] = np.nan
    x[50, 1, 1] = 5                        # one spike of 5 counts on an otherwise constant cell
    act = CellActivity((2, 2))
    act.add(x)
    found = moving_cells(act, np.ones((2, 2), bool), None, step=1)
    assert found.cells.tolist() == [[1, 1]] and found.threshold == 4.0


# --------------------------------------------------------------------------- unused_cells


def test_unused_cells_are_accepted_outside_blocks_and_refused_inside():
    lay = parse_layout(draft_layout(unused=[[0, 10], [4, 4]]), "draft.json")
    assert not lay.unmapped_mask[0, 10] and not lay.unmapped_mask[4, 4] and lay.unmapped_mask[0, 11]
    assert not lay.unmapped_mask[0:4, 0:4].any() and not lay.unmapped_mask[8:].any()
    assert lay.to_dict()["unused_cells"] == [[0, 10], [4, 4]]
    with pytest.raises(ValueError, match=r"unused cell \[1, 1\] lies inside block 'index_tip'"):
        parse_layout(draft_layout(unused=[[1, 1]]), "draft.json")
    doc = draft_layout(unused=[[5, 5]])
    doc["bend_cells"] = [[5, 5]]
    with pytest.raises(ValueError, match=r"both a bend cell and an unused cell"):
        parse_layout(doc, "draft.json")


def test_unmapped_moving_finds_exactly_the_forgotten_live_cells():
    act = CellActivity(GRID)
    act.add(knit_counts())
    found = unmapped_moving(act, parse_layout(draft_layout(), "draft.json"))
    assert sorted(map(tuple, found.cells.tolist())) == THUMB
    assert found.noise == pytest.approx(NOISE, rel=0.25)
    assert (found.ranges > 100).all()


# --------------------------------------------------------------------------- at ingest


def _ingest(tmp_path: Path, layout_doc: dict, capsys) -> tuple[int, dict, dict, str]:
    layouts = tmp_path / "gloves"
    layouts.mkdir(exist_ok=True)
    (layouts / f"{layout_doc['layout_id']}.json").write_text(json.dumps(layout_doc))
    write_glove_only(tmp_path / "raw" / "rec_a", layout_doc["layout_id"], knit_counts())
    out = tmp_path / "ds"
    capsys.readouterr()
    rc = ingest_cli("--layouts", layouts, "--pipeline", "native", tmp_path / "raw", out)
    err = capsys.readouterr().err
    record = load_episodes(out)[0]
    report = json.loads((out / "reports" / "ingest.json").read_text())
    return rc, record, report, err


def test_ingest_reports_unmapped_moving_cells_in_record_report_and_stderr(tmp_path, capsys):
    rc, record, report, err = _ingest(tmp_path, draft_layout(), capsys)
    assert rc == 0
    entry = record["unmapped_moving"]["right"]
    assert entry["count"] == 24 and sorted(map(tuple, entry["cells"])) == THUMB
    assert len(entry["range"]) == 24 and min(entry["range"]) > entry["threshold"]
    assert report["unmapped_moving"]["nat-rec_a"]["right"]["layout"] == "knit_right_16x16"
    assert report["unmapped_moving"]["nat-rec_a"]["right"]["count"] == 24
    line = next(x for x in err.splitlines() if "outside every block" in x)
    assert "episode nat-rec_a" in line and "right hand (layout knit_right_16x16)" in line
    assert "24 cell(s)" in line and "unused_cells" in line


def test_unused_cells_silence_the_finding(tmp_path, capsys):
    rc, record, report, err = _ingest(tmp_path, draft_layout(unused=[list(c) for c in THUMB]), capsys)
    assert rc == 0
    assert "unmapped_moving" not in record and report["unmapped_moving"] == {}
    assert "outside every block" not in err


# --------------------------------------------------------------------------- htdata layouts check --against / suggest


def _recordings(tmp_path: Path) -> tuple[Path, list[Path]]:
    gloves = tmp_path / "gloves"
    gloves.mkdir()
    layout = gloves / "knit_right_16x16.json"
    layout.write_text(json.dumps(draft_layout()))
    recs = [write_glove_only(tmp_path / "raw" / "rec_a", "knit_right_16x16", knit_counts(seed=1)),
            write_glove_only(tmp_path / "raw" / "rec_b", "knit_right_16x16", knit_counts(seed=2, rest_shift=60))]
    return layout, recs


def test_check_against_lists_the_unmapped_moving_cells_with_their_activity(tmp_path, capsys):
    from htdata.cli import main

    layout, recs = _recordings(tmp_path)
    assert main(["layouts", "check", str(layout), "--against", *map(str, recs)]) == 1
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.lstrip().startswith("[")]
    listed = {(int(r[0].strip("[,")), int(r[1].strip("],"))) for r in rows}
    assert listed == set(THUMB) and len(rows) == 2 * len(THUMB)        # per recording, each with its range
    assert all(float(r[2]) > 100 for r in rows)
    assert "FINDING: 24 distinct cell(s)" in out
    # the same layout with the thumb strip declared unused: nothing to find, exit 0
    layout.write_text(json.dumps(draft_layout(unused=[list(c) for c in THUMB])))
    assert main(["layouts", "check", str(layout), "--against", *map(str, recs)]) == 0
    assert "no cell outside the blocks moves" in capsys.readouterr().out


def test_check_against_a_recording_of_another_grid_is_one_line(tmp_path, capsys):
    from htdata.cli import main

    layout, _ = _recordings(tmp_path)
    npy = tmp_path / "rows.npy"
    np.save(npy, np.zeros((10, 8, 8), np.float32))
    assert main(["layouts", "check", str(layout), "--against", str(npy)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "rows.npy" in err and "8x8" in err and "16x16" in err


def test_suggest_writes_a_loadable_layout_covering_exactly_the_live_cells(tmp_path, capsys):
    from htdata.cli import main
    from htdata.glove.layouts import load_layout

    _, recs = _recordings(tmp_path)
    out = tmp_path / "My Knit Glove.json"
    assert main(["layouts", "suggest", *map(str, recs), str(out)]) == 0
    printed = capsys.readouterr().out
    lay = load_layout(out)
    assert lay.layout_id == "my_knit_glove" and lay.hand == "right" and lay.grid == GRID
    assert lay.value == {"convention": "direct", "max": lay.value["max"], "step": 1}
    live = {tuple(c) for c in np.argwhere(lay.live_mask).tolist()}
    want = set(THUMB) | {(r, c) for r in range(4) for c in range(4)} | {(r, c) for r in range(8, 16) for c in range(16)}
    assert live == want                         # the rest shift of rec_b (60 counts) is not movement
    # the index tip and the thumb strip whole, the 8x16 palm cut in two near-square blocks (one per place)
    boxes = sorted((b.rows[0], b.rows[1], b.cols[0], b.cols[1]) for b in lay.blocks)
    assert boxes == [(0, 3, 0, 3), (0, 3, 10, 15), (8, 15, 0, 7), (8, 15, 8, 15)]
    assert len({b.place for b in lay.blocks}) == len(lay.blocks)
    assert "168 moving cell(s)" in printed and "placeholder" in printed
    assert main(["layouts", "suggest", *map(str, recs), str(out)]) == 1      # refuses to overwrite
    assert "exists" in capsys.readouterr().err
    # the suggested layout passes its own check
    assert main(["layouts", "check", str(out), "--against", *map(str, recs)]) == 0


def test_suggest_from_npy_needs_a_hand_and_something_that_moves(tmp_path, capsys):
    from htdata.cli import main

    npy = tmp_path / "quiet.npy"
    np.save(npy, 550 + np.random.default_rng(0).normal(0, 3, (300, 8, 8)).astype(np.float32))
    assert main(["layouts", "suggest", str(npy), str(tmp_path / "x.json")]) == 1
    assert "--hand" in capsys.readouterr().err
    assert main(["layouts", "suggest", str(npy), str(tmp_path / "x.json"), "--hand", "left"]) == 1
    assert "no cell moves" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


# --------------------------------------------------------------------------- the sample raw-count glove (slow wander)


@pytest.fixture(scope="module")
def rawglove():
    from htdata.synthetic.rawglove import corpus_clips

    return corpus_clips(0)


def test_slow_rest_wander_is_not_movement_on_the_sample_raw_glove(rawglove):
    from htdata.glove.activity import moving_threshold
    from htdata.synthetic.rawglove import draft_layout_doc, unmapped_truth

    units, clips = rawglove
    draft = parse_layout(draft_layout_doc("right"), "draft")      # thumb tip forgotten, the gaps not declared
    old_false = 0
    for clip in clips:
        act = CellActivity(draft.grid)
        act.add(clip.counts["right"])
        found = unmapped_moving(act, draft)
        truth = unmapped_truth(clip, "right", units["right"], draft)
        hit = np.zeros(draft.grid, bool)
        hit[tuple(found.cells.T)] = True
        explained = truth["pressed"] | truth["light"] | truth["ghost"] | truth["loud"]
        assert not (hit & ~explained).any(), f"{clip.name}: resting gap cells called moving"
        # listed: as moving, or (a forgotten sensor held through the glove's quiet blocks falls when released)
        # as cross-talk; never hidden
        listed = hit.copy()
        listed[tuple(found.crosstalk.T)] = True
        assert (listed & truth["pressed"]).sum() >= 0.8 * truth["pressed"].sum()
        assert found.wander > 1.0 and found.threshold > MOVING_K * found.noise
        # today's rule (fast noise only) calls the gaps' slow wander movement
        old = draft.unmapped_mask & (act.range > moving_threshold(found.noise, 1))
        old_false += int((old & ~explained).sum())
    assert old_false > 20


def test_suggest_finds_the_true_sensor_areas_of_the_sample_raw_glove(rawglove):
    from htdata.glove.layoutsuggest import suggest_layout
    from htdata.synthetic.rawglove import glove_layout

    _, clips = rawglove
    acts = []
    for clip in clips:
        acts.append(CellActivity((32, 32)))
        acts[-1].add(clip.counts["right"])
    doc, summary = suggest_layout(acts, "right", "suggested", True, [c.name for c in clips])
    # the sensor is one connected knit (the palm touches every finger strip and the thumb): still at least the
    # four fingers, the thumb and the palm apart (issue 34: >= 9 blocks), and exactly the live cells
    assert len(doc["blocks"]) >= 9
    truth = glove_layout("right").live_mask
    got = parse_layout(doc, "suggested").live_mask
    # cell precision against the true layout, recall of the live cells the clips pressed (suggest finds what was
    # pressed: the real glove's twelve clips press nearly all of it, tests/glove/test_realglove_cells.py)
    pressed = truth & np.any([c.pressure["right"].max(axis=0) >= 0.05 for c in clips], axis=0)
    assert (got & truth).sum() >= 0.9 * got.sum() and (got & pressed).sum() >= 0.9 * pressed.sum()
    assert summary["left_out"] and summary["wander"] > 1.0       # the cross-talk column, loud cells: not blocks


# --------------------------------------------------------------------------- real-glove behaviour, built here


def _quiet_glove(frames: int, seed: int = 3) -> np.ndarray:
    """(T,16,16) raw counts of a glove at rest like the real knit one: smooth rest wander of a couple of counts,
    a glove-wide dip of ~5 counts now and then, float16 counts (0.5-count steps near 550)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None]
    x = 550 + rng.uniform(-25, 25, (1, *GRID)) + 1.5 * np.sin(2 * np.pi * t / rng.uniform(40, 120, (1, *GRID)))
    x -= 5.0 * np.exp(-0.5 * ((t % 60 - 30) / 4.0) ** 2)                   # the glove-wide dips
    return x.astype(np.float16).astype(np.float32)


def test_a_short_resting_clip_never_moves_and_a_press_of_the_contact_level_does():
    draft = parse_layout(draft_layout(), "draft.json")
    x = _quiet_glove(135)                                   # 4.5 s: little slow wander to measure
    act = CellActivity(GRID)
    act.add(x)
    quiet = unmapped_moving(act, draft)
    assert len(quiet) == 0 and len(quiet.crosstalk) == 0
    # the contact floor (0.02 x value.max = 20.5 counts) holds although noise and wander are tiny here
    assert quiet.threshold == pytest.approx(MOVING_MIN_FULL_SCALE * 1023)
    pressed = x.copy()
    pressed[60:90, 1, 12] += 30.0                           # a forgotten thumb cell pressed lightly
    act = CellActivity(GRID)
    act.add(pressed)
    assert unmapped_moving(act, draft).cells.tolist() == [[1, 12]]


def test_cells_that_only_fall_below_rest_are_crosstalk_and_do_not_fail_the_check(tmp_path, capsys):
    from htdata.cli import main

    x = _quiet_glove(600)
    grip = np.zeros(600)
    grip[200:420] = 1.0
    x[:, 8:16, 0:16] += 200 * grip[:, None, None]           # the palm grips ...
    x[:, 5, 4:9] -= 40 * grip[:, None]                      # ... and the gap row beside it falls (cross-talk)
    act = CellActivity(GRID)
    act.add(x)
    draft = parse_layout(draft_layout(unused=[list(c) for c in THUMB]), "draft.json")
    found = unmapped_moving(act, draft)
    assert len(found) == 0 and sorted(found.crosstalk.tolist()) == [[5, c] for c in range(4, 9)]
    assert found.record()["crosstalk"]["count"] == 5 and found.record()["count"] == 0
    assert act.rest_level(draft.live_mask)[5, 4] == pytest.approx(float(np.median(x[:200, 5, 4])), abs=3)
    # the same cells rising are forgotten sensors; a cell that rises and falls rises
    up = x.copy()
    up[:, 5, 4:9] += 80 * grip[:, None]
    up[100:150, 6, 6] += 40
    up[450:500, 6, 6] -= 40
    act_up = CellActivity(GRID)
    act_up.add(up)
    assert sorted(unmapped_moving(act_up, draft).cells.tolist()) == [[5, c] for c in range(4, 9)] + [[6, 6]]
    # an inverted glove (larger = less pressure): the same falling cells press
    inverted = parse_layout({**draft_layout(unused=[list(c) for c in THUMB]),
                             "value": {"convention": "inverted", "max": 1023, "step": 1}}, "inv.json")
    assert sorted(unmapped_moving(act, inverted).cells.tolist()) == [[5, c] for c in range(4, 9)]
    # `layouts check --against`: listed as cross-talk, exit 0
    layout = tmp_path / "draft.json"
    layout.write_text(json.dumps(draft_layout(unused=[list(c) for c in THUMB])))
    np.save(tmp_path / "grip.npy", x)
    capsys.readouterr()
    assert main(["layouts", "check", str(layout), "--against", str(tmp_path / "grip.npy")]) == 0
    out = capsys.readouterr().out
    assert "no cell outside the blocks rises; 5 only fall below rest (cross-talk" in out and "[5, 4]" in out
