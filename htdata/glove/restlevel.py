"""Rest-level helpers of the normaliser: which frames are quiet, and the per-glove calibration file.

`quiet_frames` picks the resting frames of a window (the quietest span,
the drift-following baseline and raw-row health use it);
`load_taxel_calibration` reads a glove's measured per-taxel offset and gain.
"""

from __future__ import annotations

import numpy as np

from htdata.errors import ConfigError


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


def windowed_quiet(level: np.ndarray, window: int) -> np.ndarray:
    """(T,) bool: `quiet_frames` of each window of `window` frames (a short tail joins the window before it).

    Per window, not over the episode: a rest level that drifts by a few counts over minutes would leave
    every frame after the drift out of an episode-wide choice.
    """
    out = np.zeros(len(level), bool)
    for a, b in windows(len(level), window):
        out[a:b] |= quiet_frames(level[a:b])
    return out


REST_MARGIN = 0.01   # unit values: a frame whose mean sits this far above the episode's low is not at rest


def resting_frames(level: np.ndarray, window: int) -> np.ndarray:
    """(T,) bool: the episode's resting frames for its noise floor: `windowed_quiet`, and within REST_MARGIN
    of the episode's low (its 5th percentile): a window gripped throughout has no rest to offer (a grip
    raises the mean live value of a knit glove by 0.15-0.3, a rest level drifting over minutes by < 0.005)."""
    quiet = windowed_quiet(level, window)
    finite = np.isfinite(level)
    if not finite.any():
        return quiet
    return quiet & (np.where(finite, level, np.inf) <= np.percentile(level[finite], 5) + REST_MARGIN)


def windows(T: int, window: int):
    """(start, stop) of consecutive windows of `window` (>= 2) frames over T; a short tail (under half a
    window) is the last full window instead."""
    w = max(2, int(window))
    for a in range(0, T, w):
        b = min(T, a + w)
        if b - a < max(2, w // 2) and a > 0:
            a = max(0, b - w)
        yield a, b


def rest_spread(residual: np.ndarray) -> np.ndarray:
    """(H,W) robust spread of (T,H,W) resting values around the baseline: 1.4826 x median |residual|.

    About the BASELINE, not about each taxel's own median: a rest level that wanders away from the
    baseline over the episode widens the spread (and so the noise floor) by as much.
    """
    with nan_quiet():
        return np.float32(1.4826) * np.nanmedian(np.abs(residual), axis=0)


REST_WARN_LEVEL = 0.1   # a glove whose resting cells read this much with baseline "none" gets a warning


def rest_level_warning(hand: str, layout, cfg, lo: np.ndarray, hi: np.ndarray) -> str | None:
    """One warning line when baseline "none" leaves a glove's rest reading as pressure (None otherwise).

    `lo` / `hi`: (H,W) per-cell min / max raw values of the episode (htdata.glove.activity.CellActivity);
    the rest level is the median over live cells of the lowest pressure each cell read.
    """
    if cfg.baseline != "none" or cfg.taxel_calibration_sha256:
        return None
    live = np.asarray(layout.live_mask, bool)
    raw = (hi if cfg.convention == "inverted" else lo)[live]
    raw = raw[np.isfinite(raw)]
    if not raw.size:
        return None
    rest = float(np.median(raw))
    reads = (cfg.max_value - rest) / cfg.max_value if cfg.convention == "inverted" else rest / cfg.max_value
    if reads < REST_WARN_LEVEL:
        return None
    lid = layout.layout_id
    return (f"warning: {hand} hand (layout {lid}): rest level {rest:.4g} of {cfg.max_value:g}: covered pixels read "
            f">= {reads:.2f} at rest with baseline = \"none\"; set a baseline ([normalise.{lid}] baseline = "
            f"\"quietest\", noise_k = 3)")


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
