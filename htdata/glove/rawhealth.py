"""Taxel health from the RAW rows, in glove units: what the glove does, whatever the normalisation.

htdata/glove/health.py classifies normalised values, so its verdict follows the
calibration (a rest-window baseline turns a stuck cell into a quiet one, a
missing baseline turns every resting taxel into a "stuck" one). Where a
dataset stores its raw rows, `classify_raw` looks at the raw counts
instead. Values are taken in the pressure direction, u = raw / max
("direct") or (max - raw) / max ("inverted"), so fractions below are of the
glove's FULL SCALE (`value.max`) and steps are its quantisation step
(`value.step`, 1/1000 of full scale when the layout gives none). Per taxel:
rest = its 5th percentile over the episode, rise = u - rest. Each live taxel
gets at most one class, in this order:

- saturated (at rest): its rest level is at the top of the scale
  (rest >= SATURATED_REST of full scale): it reads full pressure untouched;
- stuck: constant (p99 - p1 <= STUCK_STEPS steps) at a level more than
  STUCK_SHARE of full scale away from the glove's rest (median of the
  taxels' rest levels);
- dead: never rises (p99 of rise < DEAD_RISE of full scale) although it was
  exercised: in >= EXERCISED_FRAMES frames, >= 3 same-block neighbours (two
  of them on opposite sides) rose >= PRESSED_RISE of full scale;
- noisy: its high-frequency level (75th percentile of |second difference|)
  above NOISY_MIN_STEPS steps and NOISY_RATIO x its neighbours' median;
- drifting: its rest level moves by more than DRIFT_SHARE of full scale
  between the first and last quarter of the episode. The rest level of a
  quarter is read from quiet frames only: the quarter's resting frames
  (`htdata.glove.restlevel.quiet_frames`; a quarter whose resting mean sits
  DRIFT_GRIP_LEVEL above the episode's low is gripped throughout and leaves
  drift untold), and of those the taxel's own lower values (its
  DRIFT_REST_PCT percentile there), so a grip held or changed inside a
  quarter is not taken for drift. Only assessed on episodes of at least
  DRIFT_MIN_FRAMES frames (60 s at 30 fps): over a 5-30 s manipulation clip
  a rest level moving by 10 counts is a grip change or slow wander, not a
  sensor drifting (issue 27). Shorter episodes say so ("drift_assessed":
  false, and the health map's legend);
- crosstalk: lights up (rise > CROSSTALK_RISE of full scale) along a raw
  row / column with nothing pressed beside the line: no rise over half that
  within health.CROSSTALK_REACH lines (health._crosstalk).

Not faults, reported beside them: "unexercised" = never rose and never
exercised (an idle finger); "unmapped" = the layout's unmapped cells
(outside every block, not bend cells, not `unused_cells`) that MOVE by the
one moving-cell rule of htdata/glove/activity.py (the rule ingest and
`htdata layouts check --against` use): a live cell the layout does not place
("unmapped_moving", with their raw-grid cells).
"""

from __future__ import annotations

import numpy as np

from htdata.glove import health
from htdata.glove.activity import CellActivity, rule_text, unmapped_moving
from htdata.glove.glovevalue import pressure_share
from htdata.glove.health import CLASSES, MIN_FRAMES, TaxelGrid, _crosstalk, _exercised, _neighbour_median
from htdata.glove.restlevel import nanpercentile_columns, quiet_frames

SATURATED_REST = 0.98        # rest level >= this share of full scale
STUCK_STEPS = 0.5            # p99 - p1 within half a quantisation step: constant (a live taxel flickers a count)
STUCK_SHARE = 0.10           # ... and this far from the glove's rest level (102 counts of 1023; offsets are ~25)
DEAD_RISE = 0.01             # p99 of its rise below this share of full scale (10 counts of 1023): never responds
PRESSED_RISE = 0.05          # a neighbour "pressed" for the dead test (51 counts of 1023)
NOISY_MIN_STEPS = 16          # 75th pct of |2nd difference|: ~1.2 x 2.45 x std, so a taxel of std > ~5 steps
NOISY_RATIO = 4.0
DRIFT_SHARE = 0.01           # rest level moving more than this (10 counts of 1023) over the episode
DRIFT_MIN_FRAMES = 1800      # 60 s at 30 fps: shorter clips cannot tell drift from wander and grip changes
DRIFT_GRIP_LEVEL = 0.01      # a quarter whose quiet mean sits this far above the episode's low is gripped
DRIFT_REST_PCT = 25          # a taxel's rest level in a quarter: this percentile of its quiet frames
CROSSTALK_RISE = health.CONTACT_LEVEL   # health._crosstalk lights a taxel above it
DEFAULT_STEP_SHARE = 1e-3    # step when the layout gives none

THRESHOLDS = {"saturated": f"rest >= {SATURATED_REST:.0%} of full scale",
              "stuck": f"constant (<= {STUCK_STEPS} step) and > {STUCK_SHARE:.0%} of full scale off the glove's rest",
              "dead": f"never rises {DEAD_RISE:.0%} of full scale while its neighbours rise {PRESSED_RISE:.0%}",
              "noisy": f"high-frequency level > {NOISY_MIN_STEPS} steps and {NOISY_RATIO:g}x its neighbours'",
              "drifting": f"rest level (quiet frames) moves > {DRIFT_SHARE:.0%} of full scale, first vs last quarter "
                          f"of clips >= {DRIFT_MIN_FRAMES} frames",
              "crosstalk": f"a raw row/column rises > {CROSSTALK_RISE:.0%} of full scale with nothing rising "
                           f"{health.CROSSTALK_SIDE_LEVEL:.0%} within {health.CROSSTALK_REACH} lines beside it",
              "unexercised": f"never rose {DEAD_RISE:.0%} of full scale, neighbours never pressed",
              "unmapped": f"outside every block and unused_cells, {rule_text()}"}


def pressure_units(raw: np.ndarray, value: dict) -> np.ndarray:
    """Raw glove units -> share of full scale in the pressure direction (float32, NaN kept)."""
    return pressure_share(raw, value.get("convention"), float(value["max"]))


def _drifting(u: np.ndarray) -> tuple[np.ndarray, bool]:
    """((L,) bool drifting, assessed): rest level of the first vs the last quarter's resting frames."""

    T = len(u)
    if T < DRIFT_MIN_FRAMES:
        return np.zeros(u.shape[1], bool), False
    q = T // 4
    level = np.nanmean(u, axis=1)
    floor = np.nanpercentile(level, 5)
    ends = []
    for part in (slice(0, q), slice(T - q, T)):
        # the quarter's own resting frames (a whole-episode choice would drop a quarter the drift has raised),
        # and only when they are at rest: a quarter gripped throughout has no rest level to compare
        quiet = np.flatnonzero(quiet_frames(level[part]))
        if quiet.size < 5 or np.nanmedian(level[part][quiet]) > floor + DRIFT_GRIP_LEVEL:
            return np.zeros(u.shape[1], bool), False
        ends.append(nanpercentile_columns(u[part][quiet], DRIFT_REST_PCT))   # a taxel pressed there: its lows
    return np.abs(ends[1] - ends[0]) > DRIFT_SHARE, True


def classify_raw(raw: np.ndarray, layout, taxels: TaxelGrid | None = None) -> dict:
    """(T,H,W) raw rows of one episode hand -> health dict like health.classify, from glove units.

    Adds "basis": "raw", "drift_assessed", "unmapped_cells" (cells outside every block),
    "unmapped_moving" (how many rise >= DEAD_RISE) and their cells.
    """
    taxels = taxels or TaxelGrid.of(layout)
    grid = np.asarray(raw, np.float32)
    T = grid.shape[0]
    live = np.asarray(layout.live_mask, bool)
    u_all = pressure_units(grid, layout.value)
    x = u_all[:, live]
    L = x.shape[1]
    out = {"assessed": T >= MIN_FRAMES, "frames": int(T), "live": int(L), "basis": "raw",
           "counts": {c: 0 for c in CLASSES}, "cells": {c: [] for c in CLASSES}, "unexercised": 0,
           "unexercised_cells": [], "drift_assessed": False, "unmapped_cells": 0, "unmapped_moving": 0, "unmapped_moving_cells": []}
    if not out["assessed"] or L == 0:
        return out
    step = float(layout.value.get("step") or 0.0) / float(layout.value["max"]) or DEFAULT_STEP_SHARE
    with np.errstate(invalid="ignore"):
        p1, p50, p99 = nanpercentile_columns(x, [1, 50, 99])
        rest = nanpercentile_columns(x, 5)
        rise = np.clip(np.nan_to_num(x - rest, nan=0.0), 0.0, 1.0)
    glove_rest = float(np.nanmedian(rest))
    saturated = rest >= SATURATED_REST
    flat = (p99 - p1) <= STUCK_STEPS * step + 1e-7
    stuck = flat & (np.abs(p50 - glove_rest) > STUCK_SHARE) & ~saturated
    crosstalk = _crosstalk(rise, taxels)     # lit above health.CONTACT_LEVEL (= CROSSTALK_RISE); lighter rises beside count
    exercised = _exercised_raw(rise, taxels, crosstalk)
    never = np.percentile(rise, 99, axis=0) < DEAD_RISE
    hf = nanpercentile_columns(np.abs(np.diff(x, n=2, axis=0)), 75)
    noisy = (hf > NOISY_MIN_STEPS * step) & (hf > NOISY_RATIO * _neighbour_median(hf, taxels))
    drifting, out["drift_assessed"] = _drifting(x)
    label = np.full(L, -1, np.int64)
    masks = {"saturated": saturated, "stuck": stuck, "dead": never & exercised, "noisy": noisy,
             "drifting": drifting, "crosstalk": crosstalk}
    for name in CLASSES:
        label[(label < 0) & masks.get(name, np.zeros(L, bool))] = CLASSES.index(name)
    out["unexercised"] = int((never & ~exercised & (label < 0)).sum())
    out["unexercised_cells"] = taxels.cells[never & ~exercised & (label < 0)].tolist()
    for k, name in enumerate(CLASSES):
        hit = np.flatnonzero(label == k)
        out["counts"][name] = int(hit.size)
        out["cells"][name] = taxels.cells[hit].tolist()
    _unmapped(grid, layout, out)
    return out


def _exercised_raw(rise: np.ndarray, taxels: TaxelGrid, ignore: np.ndarray) -> np.ndarray:
    """health._exercised on rises: neighbours 'pressed' when they rose >= PRESSED_RISE of full scale."""

    # _exercised compares with health.PRESSED_LEVEL: scale the rises so that PRESSED_RISE maps onto it
    return _exercised(rise * (health.PRESSED_LEVEL / PRESSED_RISE), taxels, ignore)


def _unmapped(raw: np.ndarray, layout, out: dict) -> None:
    """The layout's unmapped cells (not bend, not unused): how many, and which move by the one moving-cell rule."""
    mask = np.asarray(layout.unmapped_mask, bool)
    out["unmapped_cells"] = int(mask.sum())
    if not mask.any():
        return
    activity = CellActivity(raw.shape[1:])
    activity.add(raw)
    found = unmapped_moving(activity, layout)
    out["unmapped_moving"] = len(found)
    out["unmapped_moving_cells"] = sorted(found.cells.tolist())


def drift_status(summary: dict) -> str | None:
    """How far drift was assessed in a merged health summary (`health.merge_counts`); None without raw rows."""
    told, untold = summary.get("drift_assessed", 0), summary.get("drift_not_assessed", 0)
    if not told and not untold:
        return None
    if not told:
        return (f"not assessed: every episode is shorter than {DRIFT_MIN_FRAMES} frames (too short to tell drift "
                f"from wander)")
    if untold:
        return f"assessed on {told} of {told + untold} episodes (the others are shorter than {DRIFT_MIN_FRAMES} frames)"
    return "assessed"

