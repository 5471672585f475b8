"""Taxel health from raw counts (htdata/glove/rawhealth.py): one test per class a real knit glove has, on synthetic
raw counts with the real glove's numbers (rest ~550 of 1023, per-taxel offsets, ~1 count of noise)."""

import warnings

import numpy as np
import pytest

from htdata.glove.layouts import parse_layout
from htdata.glove.rawhealth import DRIFT_MIN_FRAMES, classify_raw
from htdata.synthetic.rawglove import GloveUnit, corpus_clips, draft_layout_doc, glove_layout, make_clip, unmapped_truth

LAYOUT = glove_layout("right")


@pytest.fixture(scope="module")
def glove():
    unit = GloveUnit.make("right", 7)
    # a pressed clip (so neighbours of dead cells are exercised), 20 s at 30 fps
    clip = make_clip("h", "power_grasp", 600, "rest", 7, {"right": unit})
    return unit, clip.counts["right"].astype(np.float32)


def _long(raw: np.ndarray) -> np.ndarray:
    """A clip long enough to tell drift (DRIFT_MIN_FRAMES): the 20 s clip, then the hand resting on (its last
    second repeated with the glove's noise and wander re-drawn by a shuffle of that second's rows)."""
    rng = np.random.default_rng(5)
    tail = raw[-30:]
    rest = tail[rng.integers(0, 30, DRIFT_MIN_FRAMES - len(raw) + 30)]
    return np.concatenate([raw, rest])


def _found(health, name):
    return {tuple(c) for c in health["cells"][name]}


def test_each_planted_fault_is_its_class(glove):
    unit, raw = glove
    raw = raw.copy()
    for r, c in unit.faults.cells["dead"]:       # press around each dead cell now and then: exercised, never rising
        for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1)):
            if 0 <= r + dr < 32 and 0 <= c + dc < 32 and LAYOUT.live_mask[r + dr, c + dc]:
                raw[100:160, r + dr, c + dc] += 120.0
    h = classify_raw(raw, LAYOUT)
    assert h["assessed"] and h["basis"] == "raw"
    planted = unit.faults.cells
    assert _found(h, "saturated") == set(planted["saturating"])
    assert _found(h, "stuck") == set(planted["stuck"])
    assert _found(h, "noisy") == set(planted["noisy"])
    assert _found(h, "dead") <= set(planted["dead"]) and _found(h, "dead")    # dead where it was exercised
    assert h["unexercised"] > 0                                             # idle taxels: not dead, not healthy


def test_a_drifting_taxel_is_flagged(glove):
    _, raw = glove
    raw = _long(raw)
    r, c = 20, 14                                  # a palm taxel: its rest creeps 30 counts over the episode
    raw[:, r, c] += np.linspace(0, 30, len(raw)).round()
    h = classify_raw(raw, LAYOUT)
    assert h["drift_assessed"] and (r, c) in _found(h, "drifting")
    short = classify_raw(raw[:DRIFT_MIN_FRAMES - 1], LAYOUT)
    assert not short["drift_assessed"] and not short["cells"]["drifting"]


def test_drift_is_read_from_quiet_frames_and_not_told_on_short_clips(glove):
    from htdata.inspect.healthmap import _legend

    _, raw = glove
    raw = _long(raw)
    # a taxel pressed through 60% of the last quarter while the rest of the glove rests: a grip, not drift
    r, c = 20, 14
    T, q = len(raw), len(raw) // 4
    raw[T - int(0.6 * q):, r, c] += 120
    h = classify_raw(raw, LAYOUT)
    assert h["drift_assessed"] and (r, c) not in _found(h, "drifting")
    # a 20 s manipulation clip whose grip changes: drift is not assessed, and the legend says so
    short = raw[:600].copy()
    short[300:, r, c] += 40
    h = classify_raw(short, LAYOUT)
    assert not h["drift_assessed"] and not h["cells"]["drifting"]
    text = " ".join(t for _, t in _legend({"raw"}, drift_told=False))
    assert "drifting: NOT ASSESSED" in text and str(DRIFT_MIN_FRAMES) in text


def test_clean_counts_flag_nothing():
    unit = GloveUnit.make("right", 11)
    unit.faults.cells = {k: [] for k in unit.faults.cells}
    unit.faults.crosstalk_cols = []
    unit.noise = np.minimum(unit.noise, 1.2)      # no loud taxels either
    raw = make_clip("c", "power_grasp", 400, "rest", 11, {"right": unit}).counts["right"].astype(np.float32)
    h = classify_raw(raw, LAYOUT)
    assert sum(h["counts"].values()) == 0, {k: v for k, v in h["cells"].items() if v}


def test_a_crosstalk_row_is_found():
    """A raw row that lights up along its length with nothing pressed beside it (the sample glove's own
    cross-talk runs in its unused column 31, which health does not look at: htdata/glove/activity.py reports it)."""
    _, clips = corpus_clips(0)
    raw = clips[0].counts["right"].astype(np.float32)
    row = 20                                               # a palm row
    live = np.flatnonzero(LAYOUT.live_mask[row])
    for k in range(6):                                     # six short swings along the whole row
        raw[30 + 40 * k:36 + 40 * k, row, live] += 60.0
    h = classify_raw(raw, LAYOUT)
    rows = {r for r, _ in _found(h, "crosstalk")}
    assert rows == {row}


def test_a_press_along_the_edge_of_a_pressed_area_is_not_crosstalk():
    """The finding of issue 43: a press whose edge line passes the contact level while the lines beside it (the
    rest of a strip 4 lines wide) are pressed more lightly is a press, not a ghost line; a ghost line lit the
    same way with nothing beside it is still found."""
    _, clips = corpus_clips(0)
    raw = clips[0].counts["right"].astype(np.float32)
    quietest = np.argsort(raw[:, LAYOUT.live_mask].mean(axis=1))[:30]
    clean = raw[np.random.default_rng(3).choice(quietest, 300)]    # the glove at rest: its noise, no press
    row, cols = 16, np.arange(10, 19)                      # palm_upper_radial, rows 12-22
    press, ghost = clean.copy(), clean.copy()
    for k in range(6):
        t = 30 + 40 * k
        press[t:t + 24, row:row + 3, cols[0]:cols[-1] + 1] += 14.0   # the strip pressed lightly (under contact)
        press[t + 9:t + 15, row, cols] += 16.0                     # its edge line passes contact at the peak
        ghost[t + 9:t + 15, row, cols] += 30.0
    assert not {r for r, _ in _found(classify_raw(press, LAYOUT), "crosstalk")} & {row, row + 1, row + 2}
    assert {r for r, _ in _found(classify_raw(ghost, LAYOUT), "crosstalk")} == {row}


def test_unmapped_cells_move_by_the_one_rule_and_unused_cells_are_honoured():
    units, clips = corpus_clips(0)
    clip, unit = clips[1], units["right"]
    raw = clip.counts["right"].astype(np.float32)
    draft = parse_layout(draft_layout_doc("right"), "draft")        # thumb tip forgotten, gaps not declared
    h = classify_raw(raw, draft)
    truth = unmapped_truth(clip, "right", unit, draft)
    found = np.zeros(truth["pressed"].shape, bool)
    found[tuple(np.asarray(h["unmapped_moving_cells"]).T)] = True
    assert h["unmapped_cells"] == int(draft.unmapped_mask.sum())
    # the forgotten thumb tip moves; every other moving cell is a ghost row or a loud cell, never the gaps'
    # slow rest wander
    assert (found & truth["pressed"]).sum() >= 0.8 * truth["pressed"].sum() > 0
    assert not (found & ~(truth["pressed"] | truth["light"] | truth["ghost"] | truth["loud"])).any()
    # the shipped layout lists the gaps in unused_cells: health counts none of them, moving or not
    moved = raw.copy()
    moved[:, 16, 25] += np.where(np.arange(len(raw)) % 60 < 30, 0, 80)  # a gap cell (row 16) that responds
    shipped = classify_raw(moved, LAYOUT)
    assert shipped["unmapped_cells"] == 0 and shipped["unmapped_moving"] == 0
    assert [16, 25] in classify_raw(moved, draft)["unmapped_moving_cells"]


def test_inverted_gloves_are_read_in_the_pressure_direction(glove):
    unit, raw = glove
    inverted = type(LAYOUT)(**{**LAYOUT.__dict__, "value": {"convention": "inverted", "max": 1023.0, "step": 1}})
    h = classify_raw(1023.0 - raw, inverted)
    assert _found(h, "saturated") == set(unit.faults.cells["saturating"])


def test_health_map_draws_unexercised_and_unmapped_cells_and_states_thresholds(glove):
    from htdata.glove.layouts import load_canonical
    from htdata.inspect.episodestats import Glove
    from htdata.inspect.healthmap import (
        UNEXERCISED,
        UNEXERCISED_INDEX,
        UNMAPPED_MOVING,
        _legend,
        draw_grid_panel,
        taxel_classes,
    )

    unit, raw = glove
    raw = raw.copy()
    raw[:, 16, 25] += np.where(np.arange(len(raw)) % 60 < 30, 0, 80)
    draft = parse_layout({**draft_layout_doc("right", forget=()), "layout_id": LAYOUT.layout_id}, "draft")
    h = classify_raw(raw, draft)
    assert [16, 25] in h["unmapped_moving_cells"]
    g = Glove(LAYOUT, load_canonical())
    per_episode = [{"hands": {"right": {"layout": LAYOUT.layout_id, "health": h}}}]
    classes = taxel_classes(per_episode, LAYOUT.layout_id, "right", g)
    idle = {tuple(c) for c in h["unexercised_cells"]}
    assert idle and all(classes[i] == UNEXERCISED_INDEX for i, c in enumerate(g.taxels.cells.tolist())
                        if tuple(c) in idle)
    panel = draw_grid_panel(g, classes, {(16, 25)})
    assert (panel == np.array(UNMAPPED_MOVING, np.uint8)).all(axis=2).any()
    assert (panel == np.array(UNEXERCISED, np.uint8)).all(axis=2).any()
    text = " ".join(t for _, t in _legend({"raw"}))
    assert "rest >= 98% of full scale" in text and "unexercised (not a fault)" in text and "unmapped, moving" in text


def test_nanpercentile_columns_equals_numpy_with_and_without_nan():
    from htdata.glove.restlevel import nanpercentile_columns

    rng = np.random.default_rng(3)
    x = rng.normal(550, 20, size=(301, 40)).astype(np.float32)
    x[rng.random(x.shape) < 0.1] = np.nan
    x[:, 7] = np.nan                  # a column never finite
    x[:299, 8] = np.nan               # a column with two finite values
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for q in (0, 1, 5, 50, 75, 99, 100, [1, 50, 99]):
            ours, ref = nanpercentile_columns(x, q), np.nanpercentile(x.astype(np.float64), q, axis=0)
            np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=0, equal_nan=True)
        clean = np.nan_to_num(x, nan=0.0)
        np.testing.assert_array_equal(nanpercentile_columns(clean, 5), np.percentile(clean.astype(np.float64), 5, axis=0))
