"""Fitting a glove's rest level: the per-taxel baseline and noise floor a `Normaliser` subtracts.

Arrays in, arrays out: the functions take unit values (`Normaliser.to_unit`
of the raw rows) and a `NormaliseConfig`; the Normaliser keeps what they
return, and carries it into the episode record (htdata.glove.normalise).

From the first frames (`fit_first_frames`): "first_frame" (the first row),
"rest_window" (the per-taxel median of the first `rest_frames`; noise_k
floors at k x 1.4826 x the window's median absolute deviation).

Baselines chosen by activity (episode-wide: the ingest reads the episode's
paired rows once more before normalising it, `fit_whole_episode`):
- "quietest": the per-taxel median of the quietest span of `rest_seconds`
  (default 1 s): the span whose mean live value is lowest (a press raises
  the value, so the hands are most at rest there), wherever it lies. A clip
  that starts mid-grasp keeps its grip instead of taking it for rest.
- "percentile": the per-taxel `baseline_percentile` (default 5) percentile
  over the whole episode: keeps every press a taxel holds for less than
  95% of the episode.
- "drift": a rest level that follows slow drift: per window of
  `drift_window_s` seconds (default 30), the per-taxel median of the
  window's quiet frames (those whose mean live value stays near the window's
  lowest: `quiet_frames`), knots at the window centres, linearly interpolated between them
  by the raw row's position in the episode (the line through the first / last
  two knots continued beyond the first / last centre). Stored as knots (`baseline` is then (K,H,W), `knot_rows`
  their row positions); `apply` needs the rows' positions (`rows=`).
For these three, the spread of `noise_k` is measured on the WHOLE episode's
resting frames (`restlevel.resting_frames`: quiet in their `drift_window_s`
window and near the episode's low): 1.4826 x the
median distance of a taxel's resting values from its baseline
(`restlevel.rest_spread`), plus half a quantisation step, so rest wander
widens the floor; the quietest second alone left 7-9% of a real glove's
resting pixels lit (issue 27).

A floor (noise_k or noise_floor > 0) is never below the layout's step (`value.step / max_value`, the
`min_floor` passed in): a taxel still in its rest window (spread 0) would otherwise flicker at one count.
"""

from __future__ import annotations

import numpy as np

from htdata.glove.restlevel import nan_quiet, quiet_frames, rest_spread, resting_frames, windows


def live_level(unit: np.ndarray, live_mask: np.ndarray) -> np.ndarray:
    """(T,) mean live value of each frame (zeros without live taxels)."""
    return np.nanmean(unit[:, live_mask], axis=1) if live_mask.any() else np.zeros(len(unit))


def quietest_span(unit: np.ndarray, live_mask: np.ndarray, rest_seconds: float, fps: float) -> slice:
    """The `rest_seconds` span (>= 2 frames) of (T,H,W) unit values whose mean live value is lowest."""
    T = unit.shape[0]
    n = min(T, max(2, int(round(rest_seconds * fps))))
    level = np.nan_to_num(live_level(unit, live_mask), nan=np.inf, neginf=np.inf)   # a damaged frame: never quiet
    run = np.convolve(level, np.ones(n), mode="valid")    # sum over each span of n frames
    start = int(np.argmin(run)) if np.isfinite(run).any() else 0
    return slice(start, start + n)


def fit_first_frames(unit: np.ndarray, cfg, min_floor: np.float32) -> tuple[np.ndarray, np.ndarray | None]:
    """(baseline (H,W), noise floor (H,W) or None without noise_k) of baseline "first_frame" / "rest_window".

    `unit` (T>0,H,W) are the episode's first rows in unit values.
    """
    grid = unit.shape[1:]
    window = unit[:1] if cfg.baseline == "first_frame" else unit[: cfg.rest_frames]
    # Median over finite samples only; a taxel never finite in the window gets baseline 0.
    finite = np.isfinite(window)
    filled = np.where(finite, window, np.nan)
    n_finite = finite.sum(axis=0)
    base = np.zeros(grid, dtype=np.float32)
    has = n_finite > 0
    if has.any():
        base[has] = np.nanmedian(filled[:, has], axis=0)
    baseline = np.clip(base, 0.0, 1.0).astype(np.float32)
    if cfg.noise_k <= 0:
        return baseline, None
    spread = np.zeros(grid, dtype=np.float32)
    if has.any():
        mad = np.nanmedian(np.abs(filled[:, has] - base[has]), axis=0)
        spread[has] = np.float32(1.4826) * mad
    floor = np.maximum(np.float32(cfg.noise_floor) + np.float32(cfg.noise_k) * spread, min_floor).astype(np.float32)
    return baseline, floor


def fit_whole_episode(unit: np.ndarray, rows: np.ndarray, fps: float, cfg, live_mask: np.ndarray,
                      min_floor: np.float32) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(baseline, knot_rows, noise floor) of baseline "quietest" / "percentile" / "drift" on a whole episode.

    `unit` (T>0,H,W) are the episode's rows in unit values, in time order, `rows`
    their positions in the episode, `fps` > 0 the glove's frame rate. The
    baseline is (H,W), or (K,H,W) knots at `knot_rows` (K,) for "drift"
    (knot_rows is None otherwise); the floor is None without noise_k.
    """
    quiet = unit[quietest_span(unit, live_mask, cfg.rest_seconds, fps)]
    knot_rows = None
    with np.errstate(invalid="ignore"), nan_quiet():
        if cfg.baseline == "quietest":
            base = np.nanmedian(quiet, axis=0)
        elif cfg.baseline == "percentile":
            base = np.nanpercentile(unit, cfg.baseline_percentile, axis=0)
        else:
            base, knot_rows = drift_knots(unit, rows, fps, live_mask, cfg.drift_window_s)
    baseline = np.clip(np.nan_to_num(base, nan=0.0), 0.0, 1.0).astype(np.float32)
    if cfg.noise_k <= 0:
        return baseline, knot_rows, None
    rest = np.flatnonzero(resting_frames(live_level(unit, live_mask), round(cfg.drift_window_s * fps)))
    at = drift_baseline_at(baseline, knot_rows, rows[rest]) if cfg.baseline == "drift" else baseline
    # + half a step: counts come in whole steps, so the median distance is only known to a step
    spread = np.float32(cfg.noise_k) * np.nan_to_num(rest_spread(unit[rest] - at), nan=0.0)
    floor = np.maximum(np.float32(cfg.noise_floor) + spread + min_floor / 2, min_floor).astype(np.float32)
    return baseline, knot_rows, floor


def drift_knots(unit: np.ndarray, rows: np.ndarray, fps: float, live_mask: np.ndarray,
                window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """((K,H,W) rest level per window of `window_s` seconds: median of its quiet frames, (K,) centre rows)."""
    level, knots, centres = live_level(unit, live_mask), [], []
    for a, b in windows(unit.shape[0], round(window_s * fps)):
        quiet = np.flatnonzero(quiet_frames(level[a:b])) + a
        knots.append(np.nanmedian(unit[quiet], axis=0))
        centres.append(float(np.mean(rows[a:b])))
    return np.stack(knots), np.asarray(centres, np.float32)


def drift_baseline_at(knots: np.ndarray, knot_rows: np.ndarray, rows) -> np.ndarray:
    """(T,H,W) drift baseline of (K,H,W) `knots` at raw row positions `rows` (linear between knots)."""
    rows = np.asarray(rows, np.float32)
    at = knot_rows
    if len(at) == 1:
        return np.broadcast_to(knots[0], (len(rows), *knots.shape[1:]))
    k = np.clip(np.searchsorted(at, rows, side="right") - 1, 0, len(at) - 2)
    # linear between knots and continued past the first / last centre (at most half a window: the ends)
    frac = ((rows - at[k]) / np.maximum(at[k + 1] - at[k], 1e-6))[:, None, None]
    return (knots[k] * (1 - frac) + knots[k + 1] * frac).astype(np.float32)
