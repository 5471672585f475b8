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
  (default 1 s): the span whose mean live value is lowest, wherever it lies.
  On a knit glove a grip moves that mean by under 0.012 of full scale, so
  the span can fall inside a grip: kept for gloves whose presses move it.
- "percentile": each cell's own rest, its `baseline_percentile` percentile
  over the whole episode: a press only raises a cell, so this keeps every
  press a cell holds for less than (100 - percentile)% of the episode.
- "drift": the same per window of `drift_window_s` seconds (each cell's
  percentile there), knots at the window centres, linearly interpolated
  between them by the raw row's position in the episode (the line through the
  first / last two knots continued beyond the first / last centre): a rest
  level that follows slow drift. Stored as knots (`baseline` is then (K,H,W),
  `knot_rows` their row positions); `apply` needs the rows' positions (`rows=`).
- "shift": the rest is the glove's (its taxel calibration's offset: a reference pooled over its
  recordings, htdata.glove.restreference, already subtracted by `to_unit`); fitted here is one
  number per window of `shift_window_s` (knots, as "drift"), the common-mode shift: the median
  over live cells of each cell's `baseline_percentile` percentile there. A grip held through a whole recording loads a few dozen of a
  glove's hundreds of cells, so it moves that median by nothing and stays pressed. May be negative
  (a glove resting below its reference), unlike the others, which are clipped to [0, 1].
For these four the noise floor is per cell (`cell_floor`): noise_k x the
cell's own rest spread, from its lower half, bounded by the glove's.
A hand's mean level is no guide on a real glove (a grip moves it by 0.6-12.5 of
1023 counts), so nothing here chooses frames by it but "quietest" (issue 34).

A floor (noise_k or noise_floor > 0) is never below the layout's step (`value.step / max_value`, the
`min_floor` passed in): a taxel still in its rest window (spread 0) would otherwise flicker at one count.
"""

from __future__ import annotations

import numpy as np

from htdata.glove.restlevel import nan_quiet, nanpercentile_columns, windows

REST_SPREAD_Z = 1.2816   # median - 10th percentile of a normal distribution, in standard deviations
GLOVE_QUANTILE = 25.0   # the glove's rest spread: this percentile of its live cells' (cell_floor)
FLOOR_CAP = 2.0         # a cell's rest spread counts up to this many times the glove's


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
    knot_rows = None
    with np.errstate(invalid="ignore"), nan_quiet():
        if cfg.baseline == "quietest":
            base = np.nanmedian(unit[quietest_span(unit, live_mask, cfg.rest_seconds, fps)], axis=0)
        elif cfg.baseline == "percentile":
            base = cell_percentile(unit, cfg.baseline_percentile)
        elif cfg.baseline == "shift":
            base, knot_rows = shift_knots(unit, rows, fps, live_mask, cfg.baseline_percentile, cfg.shift_window_s)
        else:
            base, knot_rows = drift_knots(unit, rows, fps, cfg.baseline_percentile, cfg.drift_window_s)
    low = -1.0 if cfg.baseline == "shift" else 0.0
    baseline = np.clip(np.nan_to_num(base, nan=0.0), low, 1.0).astype(np.float32)
    if cfg.noise_k <= 0:
        return baseline, knot_rows, None
    at = drift_baseline_at(baseline, knot_rows, rows) if cfg.knotted else baseline
    floor = cell_floor(unit - at, live_mask, cfg.noise_k, cfg.noise_floor, min_floor)
    return baseline, knot_rows, floor


def common_shift(unit: np.ndarray, live_mask: np.ndarray, q: float) -> float:
    """The episode's common-mode shift from its rest reference: the median over live cells of each cell's
    `q` percentile of (T,H,W) unit values (0 without a finite live cell)."""
    p = cell_percentile(unit, q)[np.asarray(live_mask, bool)]
    p = p[np.isfinite(p)]
    return float(np.median(p)) if p.size else 0.0


def shift_knots(unit: np.ndarray, rows: np.ndarray, fps: float, live_mask: np.ndarray, q: float,
                window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """((K,H,W) the common-mode shift per window of `window_s` seconds, each knot one value over the grid,
    (K,) centre rows): baseline "shift" follows the glove's slow wander like "drift", one number a window."""
    knots, centres = [], []
    for a, b in windows(unit.shape[0], round(window_s * fps)):
        knots.append(np.full(unit.shape[1:], common_shift(unit[a:b], live_mask, q), np.float32))
        centres.append(float(np.mean(rows[a:b])))
    return np.stack(knots), np.asarray(centres, np.float32)


def cell_percentile(unit: np.ndarray, q: float) -> np.ndarray:
    """(H,W) per-cell `q` percentile of (T,H,W) values over time (NaN where a cell is never finite)."""
    flat = unit.reshape(len(unit), -1)
    return np.asarray(nanpercentile_columns(flat, q), np.float32).reshape(unit.shape[1:])


def cell_floor(residual: np.ndarray, live_mask: np.ndarray, noise_k: float, noise_floor: float,
               min_floor: np.float32) -> np.ndarray:
    """(H,W) noise floor from (T,H,W) values minus their baseline: `noise_k` x each cell's rest spread.

    A cell's rest spread is (its median - its 10th percentile) / 1.2816 (the
    standard deviation of a normal rest): a press only raises a cell, so while
    it rests at least half the episode its lower half is rest, noise and slow
    wander, whatever the rest of the hand does. The spread used is kept
    between the glove's and FLOOR_CAP times it. The glove's is the
    GLOVE_QUANTILE-th percentile over its live cells, not their median: a grip
    loads many cells of a real knit glove by a few counts for most of a clip
    (the median cell of a working hand sits 2-4 counts above its rest), the
    quietest quarter of the cells rests. Below it a cell would flicker with the
    glove's wander; above the cap a cell held pressed for most of the episode
    would take its grip for rest and hide it. Plus half a quantisation step.
    """
    flat = residual.reshape(len(residual), -1)
    p10, p50 = nanpercentile_columns(flat, [10.0, 50.0])
    spread = (np.nan_to_num(p50 - p10, nan=0.0) / REST_SPREAD_Z).reshape(residual.shape[1:])
    live = np.asarray(live_mask, bool) & np.isfinite(residual).any(axis=0)
    glove = float(np.percentile(spread[live], GLOVE_QUANTILE)) if live.any() else 0.0
    spread = np.clip(spread, glove, FLOOR_CAP * glove)
    floor = np.float32(noise_floor) + np.float32(noise_k) * spread + min_floor / 2
    return np.maximum(floor, min_floor).astype(np.float32)


def drift_knots(unit: np.ndarray, rows: np.ndarray, fps: float, q: float,
                window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """((K,H,W) rest level per window of `window_s` seconds: each cell's `q` percentile there, (K,) centre rows)."""
    knots, centres = [], []
    for a, b in windows(unit.shape[0], round(window_s * fps)):
        knots.append(cell_percentile(unit[a:b], q))
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
