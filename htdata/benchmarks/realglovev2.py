"""The real-glove measures, version 2 (the folder's README): rest taken from the glove, not the clip.

Version 1 (htdata/benchmarks/realglove.py, `HandTruth.of`) took each cell's
rest from its own 10th percentile in the same clip: a rule using that
reference passes by construction, and a grip held through a whole clip is
neither pressed nor kept. Version 2, per glove (a hand of a layout):

- rest reference `ref[cell]` = the median over the glove's clips of the
  cell's 10th percentile in each clip; a clip's common-mode shift = the
  median over live cells of (its 10th percentile - ref); rest = ref + shift;
- pressed: raw - rest > PRESSED; quiet: raw - rest < QUIET; a cell is held
  through its clip when its own 10th percentile sits > PRESSED above rest;
- held grip kept (c): the pressed (cell, frame) of the held-through cells.

Other gloves, derived from the clips (`DERIVED_GLOVES`), are measured with
the same truth (the original presses): every target must hold on each.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from htdata.benchmarks.realclips import HANDS, RealClip
from htdata.glove.layouts import Layout
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.glove.rasterise import Rasteriser
from htdata.synthetic.rawfacts import (  # the truth's one home (rawfacts.py)
    MID_GRASP,
    PRESSED,
    QUIET,
    REST_SHARE,
    START_FRAMES,
    TRUTH_PERCENTILE,
)


@dataclass
class GloveTruth:
    """Version 2 truth of one (clip, hand) over the layout's live cells, from the original counts."""
    raw: np.ndarray          # (T, L) float32 counts
    rest: np.ndarray         # (L,) the cell's rest in this clip: ref + shift
    pressed: np.ndarray      # (T, L) bool
    quiet: np.ndarray        # (T, L) bool
    held: np.ndarray         # (L,) bool: pressed through the clip (own 10th percentile > PRESSED above rest)
    rest_frames: np.ndarray  # indices of the hand's lowest-mean frames
    mid_grasp: bool          # >= MID_GRASP pressed cells on average in the first START_FRAMES frames


def glove_truths(clips: list[RealClip], hand: str, live: np.ndarray) -> dict[int, GloveTruth]:
    """{clip id: GloveTruth} of one glove: the rest reference pooled over all its clips (module docstring)."""
    raws = {c.clip: np.asarray(c.hand(hand), np.float32)[:, live] for c in clips}
    p10 = {k: np.percentile(x, TRUTH_PERCENTILE, axis=0) for k, x in raws.items()}
    ref = np.median(np.stack(list(p10.values())), axis=0)
    out = {}
    for k, x in raws.items():
        rest = ref + float(np.median(p10[k] - ref))
        above = x - rest
        pressed = above > PRESSED
        low = np.argsort(x.mean(axis=1), kind="stable")[: max(1, int(round(REST_SHARE * len(x))))]
        out[k] = GloveTruth(x, rest, pressed, above < QUIET, p10[k] - rest > PRESSED, low,
                            bool(pressed[:START_FRAMES].sum(axis=1).mean() >= MID_GRASP))
    return out


# ---- other gloves: (name, counts transform (counts of a hand, its v2 rest on the full grid), layout value) ----

def _twelve_bit(raw, rest):
    return np.minimum(raw * 4.0, 4095.0)


def _half_sensitive(raw, rest):
    return rest + (raw - rest) / 2.0


def _inverted(raw, rest):
    return 1023.0 - raw


def _low_rest_drifting(raw, rest):
    """Rest 300 counts lower and a common wander of +6 counts over the clip (the README's "several counts")."""
    ramp = np.linspace(0.0, 6.0, len(raw), dtype=np.float32)[:, None, None]
    return np.clip(raw - 300.0 + ramp, 0.0, 1023.0)


DerivedGlove = tuple[str, Callable | None, dict]
DERIVED_GLOVES: tuple[DerivedGlove, ...] = (
    ("real glove", None, {}),
    ("12-bit (x4, max 4095)", _twelve_bit, {"max": 4095}),
    ("half-sensitive", _half_sensitive, {}),
    ("inverted (1023 - raw)", _inverted, {"convention": "inverted"}),
    ("low rest, drifting (-300, +6 over the clip)", _low_rest_drifting, {}),
)
# The same gloves with a declared sensitivity (`value.press`, raw units): the half-sensitive glove at half the
# truth's PRESSED counts, and the real glove at PRESSED -+5%, which shows how closely the level must be known
# (the default's 1.5% of full scale is 15.3 counts).
DECLARED_PRESS_GLOVES: tuple[DerivedGlove, ...] = (
    ("half-sensitive, value.press 7.5", _half_sensitive, {"press": PRESSED / 2}),
    ("real glove, value.press 14.25 (-5%)", None, {"press": PRESSED * 0.95}),
    ("real glove, value.press 15.75 (+5%)", None, {"press": PRESSED * 1.05}),
)


def derived_counts(glove: DerivedGlove, raw: np.ndarray, truth: GloveTruth, live: np.ndarray) -> np.ndarray:
    """One hand's counts (T, H, W) as the derived glove reads them (float32, float16-rounded like the source)."""
    name, fn, _ = glove
    x = np.asarray(raw, np.float32)
    if fn is None:
        return x
    rest = np.zeros(x.shape[1:], np.float32)
    rest[live] = truth.rest
    rest[~live] = np.median(x[:, ~live], axis=0) if (~live).any() else 0.0
    return np.asarray(fn(x, rest), np.float16).astype(np.float32)


def derived_layout(glove: DerivedGlove, layout: Layout) -> Layout:
    return dataclasses.replace(layout, value={**layout.value, **glove[2]})


def hand_counts_v2(truth: GloveTruth, values: np.ndarray, layout: Layout, raster: Rasteriser) -> dict:
    """Numerators and denominators of the v2 measures of one (clip, hand), mergeable by addition."""
    v = values[:, layout.live_mask] > 0
    rest = truth.rest_frames
    maps = raster.render(values[rest])
    covered = raster.coverage > 0
    held = truth.pressed & truth.held[None, :]
    out = {"rest_quiet": int(truth.quiet[rest].sum()), "rest_quiet_lit": int((truth.quiet[rest] & v[rest]).sum()),
           "rest_pixels": int(covered.sum()) * len(rest), "rest_pixels_lit": int((maps[:, covered] > 0).sum()),
           "pressed": int(truth.pressed.sum()), "pressed_kept": int((truth.pressed & v).sum()),
           "held": int(held.sum()), "held_kept": int((held & v).sum()),
           "quiet": int(truth.quiet.sum()), "quiet_lit": int((truth.quiet & v).sum()),
           "start_pressed": 0, "start_kept": 0}
    if truth.mid_grasp:
        s = slice(0, START_FRAMES)
        out["start_pressed"] = int(truth.pressed[s].sum())
        out["start_kept"] = int((truth.pressed[s] & v[s]).sum())
    return out


def _ratio(a: int, b: int) -> float | None:
    return a / b if b else None


def v2_summary(total: dict, leaks: list[tuple[str, float]]) -> dict:
    """The v2 columns of a row from the summed counts and the per-(clip, hand) leakages."""
    worst = max(leaks, key=lambda x: x[1])
    return {"v2_rest_leakage_mean": float(np.mean([v for _, v in leaks])), "v2_rest_leakage_worst": worst[1],
            "v2_rest_leakage_worst_at": worst[0],
            "v2_rest_canvas_lit": _ratio(total["rest_pixels_lit"], total["rest_pixels"]),
            "v2_held_grip_kept": _ratio(total["pressed_kept"], total["pressed"]),
            "v2_held_grip_kept_start": _ratio(total["start_kept"], total["start_pressed"]),
            "v2_held_grip_kept_held_cells": _ratio(total["held_kept"], total["held"]),
            "v2_quiet_false_contact": _ratio(total["quiet_lit"], total["quiet"])}


def config_for(layout: Layout, plan: tuple[str, float] | None) -> NormaliseConfig:
    """The default config of the layout (no [normalise] table), or a baseline row's (baseline, noise_k)."""
    cfg = NormaliseConfig.from_layout_value(layout.value)
    if plan is not None:
        cfg = dataclasses.replace(cfg, baseline=plan[0], noise_k=plan[1])
        # "shift" is valid once its rest reference is set (realglove.left_out_reference validates it)
        cfg = cfg if cfg.baseline == "shift" else cfg.validate()
    return cfg


def derived_clips(glove: DerivedGlove, clips: list[RealClip],
                  layouts: dict[str, Layout]) -> tuple[list[RealClip], dict[str, Layout]]:
    """The clips and layouts as the derived glove records them (its counts, its value block)."""
    truths = {h: glove_truths(clips, h, layouts[h].live_mask) for h in HANDS}
    out = [RealClip(c.clip, c.label, c.fps, np.stack(
        [derived_counts(glove, c.hand(h), truths[h][c.clip], layouts[h].live_mask) for h in HANDS], axis=1))
        for c in clips]
    return out, {h: derived_layout(glove, layouts[h]) for h in HANDS}


def sensitivity_rows(clips: list[RealClip], layouts: dict[str, Layout],
                     gloves: tuple[DerivedGlove, ...] = DERIVED_GLOVES[:3]) -> list[dict]:
    """What the recordings say about each glove hand's sensitivity, per glove and hand (medians over clips, in
    counts): the rest spread (the 25th percentile over live cells of (median - 10th percentile) / 1.2816, as
    the noise floor's glove spread), the 99th percentile rise above the v2 rest, and the press level that
    spread x a constant would give were the constant fitted to the real left hand. The question it answers:
    could the press level (PRESSED counts on the real glove) be read off the recordings?"""
    rows, fitted = [], None
    for glove in gloves:
        clips_g, layouts_g = derived_clips(glove, clips, layouts) if glove[1] is not None else (clips, layouts)
        for hand in HANDS:
            live = layouts_g[hand].live_mask
            truths = glove_truths(clips_g, hand, live)
            spread, rise = [], []
            for c in clips_g:
                x = np.asarray(c.hand(hand), np.float32)[:, live]
                cell = (np.percentile(x, 50, axis=0) - np.percentile(x, TRUTH_PERCENTILE, axis=0)) / 1.2816
                spread.append(float(np.percentile(cell, 25)))
                rise.append(float(np.percentile(x - truths[c.clip].rest, 99)))
            s = float(np.median(spread))
            fitted = fitted or PRESSED / s          # the real glove's left hand: the first row
            rows.append({"glove": glove[0], "hand": hand, "rest_spread": s, "rise_p99": float(np.median(rise)),
                         "press_from_spread": fitted * s})
    return rows
