"""The sample raw-count glove shows the real glove's facts, measured by one script (htdata/synthetic/rawfacts.py)
on it and, where the real recordings are at hand (../shared/real_glove, or $HTDATA_REAL_GLOVE), on them too."""

import os
from pathlib import Path

import numpy as np
import pytest

from htdata.synthetic.rawfacts import (
    COMPARED,
    FACTS,
    clip_rows,
    comparison,
    corpus_facts,
    fact_failures,
    folder_rows,
    hand_facts,
    sample_rows,
)
from htdata.synthetic.rawglove import REST, GloveUnit, corpus_clips, glove_layout, make_clip
from htdata.synthetic.rawlayout import FINGER_ROWS, SEGMENT_COLS, sensor_mask

REAL = Path(os.environ.get("HTDATA_REAL_GLOVE", Path(__file__).resolve().parents[2].parent / "shared" / "real_glove"))


@pytest.fixture(scope="module")
def sample():
    return sample_rows(0)


@pytest.fixture(scope="module")
def real():
    if not (REAL / "clips").is_dir():
        pytest.skip(f"no real raw-count glove recordings at {REAL} (set HTDATA_REAL_GLOVE)")
    return folder_rows(REAL)


def test_the_sample_glove_shows_every_fact_of_the_real_glove(sample):
    rows, _ = sample
    pooled = corpus_facts(rows)
    assert fact_failures(pooled) == []
    assert {f.key for f in FACTS} <= set(pooled)


def test_the_facts_fail_on_a_glove_unlike_the_real_one():
    # integer counts, no wander, a grip pressing the whole palm by 200 counts from frame 50: the old kind of
    # synthetic glove that rules were tuned to
    live = glove_layout("right").live_mask
    rng = np.random.default_rng(0)
    raw = np.round(550.0 + rng.uniform(-25, 25, (32, 32)) + rng.normal(0, 1.0, (300, 32, 32)))
    palm = np.zeros((32, 32), bool)
    palm[0:23, 0:19] = True
    raw[50:250, palm] += 200.0
    rows = clip_rows("flat", {"left": raw.copy(), "right": raw}, {"left": live, "right": live})
    bad = "\n".join(fact_failures(corpus_facts(rows)))
    for key in ("grip_cells_max", "grip_shift_max", "fine_step", "rest_right", "below_rest_share",
                "crosstalk_moving_share", "mid_grasp_clips"):
        assert key in bad


def test_the_measures_read_what_was_planted():
    live = glove_layout("left").live_mask
    raw = np.full((120, 32, 32), 560.0, np.float32) + 0.5 * (np.arange(120) % 2)[:, None, None]   # a flicker
    raw[:60, 10:13, 5:15] += 40.0             # 30 cells pressed by 40 counts for the first 60 frames
    raw[:60, 13, 5:15] -= 12.0                # the row below them falls by 12 counts
    f = hand_facts(raw.astype(np.float16), live)
    assert f["grip_cells"] == 30 and f["contact_share"] == 0.5 and f["mid_grasp"]
    assert f["grip_shift"] == pytest.approx((30 * 40 - 10 * 12) / live.sum() + 0.5, abs=0.01)   # + the flicker
    assert f["below"] == 10 and f["rest"] == 560.0 and f["depth_max"] == 40.5
    assert f["wander"] == 0.5 and f["fast_step"] == 0.5


def test_the_wiring_is_one_connected_sensor_with_fingers_along_raw_columns():
    from scipy.ndimage import label

    inside = sensor_mask()
    assert label(inside)[1] == 1                                    # palm, fingers, thumb: one shape
    assert not inside[:, 31].any()                                  # column 31: no sensor (cross-talk)
    base, tip = SEGMENT_COLS["proximal"][0], SEGMENT_COLS["distal"][1]
    fingers = np.zeros(32, bool)
    for r0, r1 in FINGER_ROWS.values():
        assert inside[r0:r1 + 1, base:tip + 1].all()                 # a 4-row strip along the raw columns ...
        assert inside[r0:r1 + 1, base - 1].all()                     # ... whose base touches the palm
        fingers[r0:r1 + 1] = True
    assert not inside[~fingers, base:tip + 1].any()                  # rows between the strips carry nothing
    doc = glove_layout("right")
    assert doc.value["step"] == 0.25 and doc.num_live == int(inside.sum())


def test_truth_is_the_press_behind_the_counts(sample):
    _, truth = sample
    # "pressed" read from the counts alone (rise over the cell's own p10 > 15) mostly agrees with the truth
    assert all(t["precision"] > 0.6 and t["recall"] > 0.7 for t in truth), truth
    _, clips = corpus_clips(0)
    for clip in clips:
        for hand, sinks in clip.sinks.items():
            for r, c, drop in sinks:                                 # cells that fall are not pressed
                assert clip.pressure[hand][:, r, c].max() == 0 and drop > 0
        mid = clip.truth_contact(clip.working).sum(axis=1)
        if clip.start == "mid_grasp":
            assert mid[0] >= 15                                      # pressed from frame 0
        else:
            assert mid[0] == 0


def test_rest_level_and_speed_of_a_long_clip():
    units = {h: GloveUnit.make(h, 3) for h in ("left", "right")}
    clip = make_clip("c", "slice", 600, "rest", 3, units)
    for hand, raw in clip.counts.items():
        assert raw.dtype == np.float16
        rest = np.median(raw[:10].astype(np.float32)[:, glove_layout(hand).live_mask])
        assert abs(rest - REST[hand]) <= 3
    again = make_clip("c", "slice", 600, "rest", 3, units)
    assert all(np.array_equal(clip.counts[h], again.counts[h]) for h in units)   # deterministic by seed


def test_real_glove_beside_the_sample_glove(real, sample, capsys):
    rows, _ = sample
    table = comparison(real, rows)
    with capsys.disabled():
        print("\nmeasure | real min / median / max | sample min / median / max")
        for r in table:
            print(r["measure"], "|", " / ".join(f"{v:.3g}" for v in r["real"] or ()), "|",
                  " / ".join(f"{v:.3g}" for v in r["sample"] or ()))
    assert len(table) == len(COMPARED) + 1
    # the sample glove's typical (median) clip sits inside the real clips' spread, measure by measure
    outside = [r["measure"] for r in table if r["real"] and r["sample"]
               and not r["real"][0] <= r["sample"][1] <= r["real"][2]]
    assert outside == [], outside
    real_pooled = corpus_facts(real)
    assert real_pooled["working_hands"] == len({r["clip"] for r in real})
