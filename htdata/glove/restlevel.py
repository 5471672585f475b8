"""Rest-level helpers of the normaliser: which frames are quiet, and the per-glove calibration file.

`quiet_frames` picks the resting frames of a window by the hand's mean level
(raw-row health's drift check uses it);
`load_taxel_calibration` reads a glove's measured per-taxel offset and gain.
"""

from __future__ import annotations

import numpy as np

from htdata.errors import ConfigError
from htdata.glove.glovevalue import least_pressure, pressure_share


def quiet_frames(level: np.ndarray) -> np.ndarray:
    """(n,) bool: frames of a window whose mean live value is near its lowest (rest), not raised by a press.

    Near = at most the window's 10th percentile + 4 robust spreads of its lower half (+ 1e-4): a window at
    rest keeps (nearly) all its frames, so the median sits at the window's centre even while the rest
    level drifts; a press raises the level by far more and is left out.
    """
    finite = np.isfinite(level)
    if not finite.any():
        return finite
    lv = level[finite]
    low = lv[lv <= np.median(lv)]
    mad = 1.4826 * np.median(np.abs(low - np.median(low)))
    return finite & (level <= np.percentile(lv, 10) + 4 * mad + 1e-4)


def windows(T: int, window: int):
    """(start, stop) of consecutive windows of `window` (>= 2) frames over T; a short tail (under half a
    window) is the last full window instead."""
    w = max(2, int(window))
    for a in range(0, T, w):
        b = min(T, a + w)
        if b - a < max(2, w // 2) and a > 0:
            a = max(0, b - w)
        yield a, b


REST_WARN_LEVEL = 0.1   # a glove whose resting cells read this much with baseline "none" gets a warning


def rest_level_warning(hand: str, layout, cfg, lo: np.ndarray, hi: np.ndarray) -> str | None:
    """One warning line when baseline "none" leaves a glove's rest reading as pressure (None otherwise).

    `lo` / `hi`: (H,W) per-cell min / max raw values of the episode (htdata.glove.activity.CellActivity);
    the rest level is the median over live cells of the lowest pressure each cell read.
    """
    if cfg.subtracts_rest:
        return None
    live = np.asarray(layout.live_mask, bool)
    raw = least_pressure(lo, hi, cfg.convention)[live]
    raw = raw[np.isfinite(raw)]
    if not raw.size:
        return None
    rest = float(np.median(raw))
    reads = float(pressure_share(rest, cfg.convention, cfg.max_value))
    if reads < REST_WARN_LEVEL:
        return None
    lid = layout.layout_id
    return (f"warning: {hand} hand (layout {lid}): rest level {rest:.4g} of {cfg.max_value:g}: covered pixels read "
            f">= {reads:.2f} at rest with baseline = \"none\"; set a baseline (drop the baseline line from [normalise.{lid}] for the "
            f"raw-count default: baseline = \"drift\", noise_k = 5)")


class nan_quiet:
    """Silence numpy's all-NaN slice warnings (a taxel never finite gets baseline 0)."""

    def __enter__(self):
        import warnings
        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        return self._w.__exit__(*exc)


def load_taxel_calibration(path: str, grid: tuple[int, int], layout_id: str) -> tuple[np.ndarray, np.ndarray]:
    """(offset, gain) float32 (H,W) from a per-glove calibration .npz; errors name the file."""
    try:
        with np.load(path) as z:
            offset, gain = np.asarray(z["offset"], np.float32), np.asarray(z["gain"], np.float32)
    except (OSError, KeyError, ValueError) as exc:
        raise ConfigError(f"{path}: not a taxel calibration of layout {layout_id} (an .npz with offset and gain "
                          f"arrays): {exc}") from None
    for name, arr in (("offset", offset), ("gain", gain)):
        if arr.shape != tuple(grid):
            raise ConfigError(f"{path}: {name} has shape {arr.shape}, layout {layout_id} has a {grid[0]}x{grid[1]} "
                              f"grid")
        if not np.isfinite(arr).all():
            raise ConfigError(f"{path}: {name} holds NaN/Inf")
    if (gain <= 0).any():
        raise ConfigError(f"{path}: gain must be > 0 everywhere (a dead taxel: leave it out of the layout)")
    return offset, gain


def nanpercentile_columns(x: np.ndarray, q):
    """np.nanpercentile(x, q, axis=0) (linear method) for a (T, L) array, without numpy's per-column loop.

    numpy falls back to apply_along_axis (one Python call per column) as soon as one value is NaN;
    here every column is sorted at once (NaN last) and interpolated between the two order
    statistics around q * (n - 1), n = the column's finite count. A column without a finite value
    gives NaN. Equal to numpy's result up to float round-off (tests/glove/test_rawhealth.py).
    """
    x = np.asarray(x, np.float64)
    scalar = np.ndim(q) == 0
    qs = np.atleast_1d(np.asarray(q, np.float64)) / 100.0
    if not np.isnan(x).any():
        out = np.percentile(x, qs * 100.0, axis=0)
        return out[0] if scalar else out
    xs = np.sort(x, axis=0)                       # NaN sort last
    n = np.sum(~np.isnan(xs), axis=0)
    last = np.maximum(n - 1, 0)
    out = np.empty((qs.size, x.shape[1]), np.float64)
    for k, frac in enumerate(qs):
        pos = frac * last
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, last)
        t = pos - lo
        a = np.take_along_axis(xs, lo[None], axis=0)[0]
        b = np.take_along_axis(xs, hi[None], axis=0)[0]
        out[k] = np.where(t >= 0.5, b - (b - a) * (1 - t), a + (b - a) * t)   # numpy's _lerp
        out[k][n == 0] = np.nan
    return out[0] if scalar else out
