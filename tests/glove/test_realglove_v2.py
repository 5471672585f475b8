"""Real-glove measures, version 2 (htdata/benchmarks/realglovev2.py): rest from the glove, not the clip.

The construction tests need no recordings; the last ones run on ../shared/real_glove (skipping without it)
and hold the README's targets that the default meets today on every derived glove (see the bench for all).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from htdata.benchmarks.realclips import HANDS, RealClip, load_real_glove
from htdata.benchmarks.realglove import DEFAULT_ALONE, DEFAULT_TOGETHER, TARGETS, HandTruth, normalise_rows
from htdata.benchmarks.realglovev2 import (
    DERIVED_GLOVES,
    derived_clips,
    derived_counts,
    derived_layout,
    glove_truths,
)
from tests.factories.realglove import real_glove_dir


def _clips(held_cell: int = 3) -> tuple[list[RealClip], np.ndarray]:
    """Three clips of a 2x4 glove with per-cell offsets; clip 2 reads 20 counts higher everywhere (common mode)
    and holds `held_cell` 40 counts above its rest from the first frame to the last."""
    rng = np.random.default_rng(0)
    offsets = 550 + rng.uniform(-30, 30, (2, 4))
    clips = []
    for k in range(3):
        x = offsets + rng.normal(0, 1.0, (200, 2, 4))
        if k == 2:
            x += 20.0
            x.reshape(200, 8)[:, held_cell] += 40.0
        clips.append(RealClip(k, "c", 30.0, np.stack([x, x], axis=1)))
    return clips, np.ones((2, 4), bool)


@dataclasses.dataclass(frozen=True)
class _Value:
    value: dict


@dataclasses.dataclass(frozen=True)
class _Layout:
    value: dict
    live_mask: np.ndarray


def test_the_rest_comes_from_the_glove_so_a_grip_held_through_a_clip_is_pressed():
    clips, live = _clips()
    truths = glove_truths(clips, "left", live)
    held = truths[2]
    assert held.held.tolist() == [False, False, False, True, False, False, False, False]
    assert held.pressed[:, 3].all() and not held.pressed[:, [0, 1, 2, 4, 5, 6, 7]].any()
    assert held.quiet[:, [0, 1, 2, 4, 5, 6, 7]].mean() > 0.95     # the common-mode +20 is the clip's shift
    assert not truths[0].held.any() and not truths[0].pressed.any()
    # version 1 (rest from the clip itself) sees nothing pressed in the held clip
    assert not HandTruth.of(clips[2].hand("left"), live).pressed.any()


def test_derived_gloves_read_the_same_presses_their_own_way():
    clips, live = _clips()
    truth = glove_truths(clips, "left", live)[2]
    raw = clips[2].hand("left").astype(np.float32)
    by_name = {g[0].split(" ")[0]: g for g in DERIVED_GLOVES}
    half = derived_counts(by_name["half-sensitive"], raw, truth, live)
    assert np.allclose(half[:, 0, 3] - truth.rest[3], (raw[:, 0, 3] - truth.rest[3]) / 2, atol=0.5)
    inv = derived_counts(by_name["inverted"], raw, truth, live)
    assert np.allclose(inv, 1023 - raw, atol=0.5)
    assert np.allclose(derived_counts(by_name["12-bit"], raw, truth, live), raw * 4, atol=2.0)
    layout = derived_layout(by_name["inverted"], _Value({"convention": "direct", "max": 1023}))
    assert layout.value == {"convention": "inverted", "max": 1023}


@pytest.fixture(scope="module")
def real_rows():
    clips, layouts = load_real_glove(real_glove_dir())
    return clips, layouts, normalise_rows(clips, layouts, baselines=("shift",))


def _rows(rows, setting=DEFAULT_TOGETHER):
    return [r for r in rows if r["setting"].startswith(setting)]


def test_the_real_clips_hold_grips_through_a_clip_and_start_mid_grasp(real_rows):
    clips, layouts, _ = real_rows
    truths = [t for h in HANDS for t in glove_truths(clips, h, layouts[h].live_mask).values()]
    assert sum(int(t.held.sum()) for t in truths) >= 20
    assert sum(t.mid_grasp for t in truths) >= 2


@pytest.mark.parametrize("default", [DEFAULT_TOGETHER, DEFAULT_ALONE])
@pytest.mark.parametrize("glove", [g[0] for g in DERIVED_GLOVES])
def test_default_keeps_rest_dark_on_every_glove(real_rows, glove, default):
    """The inverted glove failed this (rest read as 0.45 pressure everywhere) before it got the raw-count default."""
    row, = [r for r in _rows(real_rows[2], default) if r["glove"] == glove]
    assert row["v2_rest_leakage_mean"] <= TARGETS["rest_leakage_mean"], row
    assert row["v2_rest_leakage_worst"] <= TARGETS["rest_leakage_worst"], row
    assert row["v2_quiet_false_contact"] <= TARGETS["quiet_false_contact"], row


def test_an_inverted_glove_reads_as_the_direct_one(real_rows):
    rows = {r["glove"].split(" ")[0]: r for r in _rows(real_rows[2])}
    for key in ("v2_rest_leakage_mean", "v2_held_grip_kept", "v2_held_grip_kept_start", "v2_quiet_false_contact"):
        assert rows["inverted"][key] == pytest.approx(rows["real"][key], abs=0.01), key


def test_derived_clips_keep_the_truth_of_the_original_presses():
    clips, live = _clips()
    layouts = {h: _Layout({"convention": "direct", "max": 1023}, live) for h in HANDS}
    half, lays = derived_clips(next(g for g in DERIVED_GLOVES if g[0] == "half-sensitive"), clips, layouts)
    assert [c.clip for c in half] == [c.clip for c in clips] and lays["left"].value["max"] == 1023
    rest = glove_truths(clips, "left", live)[2].rest[3]
    assert np.allclose(half[2].hand("left")[:, 0, 3] - rest, (clips[2].hand("left")[:, 0, 3] - rest) / 2, atol=0.5)


@pytest.mark.parametrize("glove", [g[0] for g in DERIVED_GLOVES])
def test_the_glove_s_own_rest_keeps_held_grips_on_every_glove(real_rows, glove):
    """baseline = "shift" on a rest reference pooled over the glove's OTHER clips (leave-one-out, as a user's
    reference is built from recordings other than the one normalised): every v2 target, every glove. The
    default, each cell's rest from its own clip, keeps 0.43-0.90 of the held grip (issue 43)."""
    row, = [r for r in _rows(real_rows[2], "shift") if r["glove"] == glove]
    assert row["v2_held_grip_kept"] >= TARGETS["held_grip_kept"], row
    assert row["v2_held_grip_kept_held_cells"] >= TARGETS["held_grip_kept"], row
    assert row["v2_rest_leakage_mean"] <= TARGETS["rest_leakage_mean"], row
    assert row["v2_rest_leakage_worst"] <= TARGETS["rest_leakage_worst"], row
    assert row["v2_quiet_false_contact"] <= TARGETS["quiet_false_contact"], row
    default, = [r for r in _rows(real_rows[2], DEFAULT_ALONE) if r["glove"] == glove]
    assert default["v2_held_grip_kept_held_cells"] < 0.9          # what the glove's rest is for


@pytest.mark.parametrize("glove", [g[0] for g in DERIVED_GLOVES])
def test_clips_ingested_together_keep_held_grips_by_default(real_rows, glove):
    """The README's held-grip target, default settings, clips of one glove ingested together: the ingest pools
    the glove's rest over them (htdata.ingest.gloverest), so a grip held through a whole clip stays pressed."""
    row, = [r for r in _rows(real_rows[2]) if r["glove"] == glove]
    for key in ("v2_held_grip_kept", "v2_held_grip_kept_start", "v2_held_grip_kept_held_cells"):
        assert row[key] >= TARGETS["held_grip_kept"], (key, row)
