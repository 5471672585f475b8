"""Glove units -> contact in [0,1], per pipeline and layout.

    inverted:  v = (max_value - p) / max_value     (OpenTouch: 3072 = no load, 0 = saturated)
    direct:    v = p / max_value                   (TouchAnything: already [0,1])
    baseline:  v -= b  per taxel, then clip at 0   (b from the first frames, see below)
    noise:     v -= f  per taxel, then clip at 0   (f = noise_floor + noise_k * rest-window spread)
    scale:     v *= scale
    clip:      true  -> clip to [0,1];
               false -> strict: a finite live value outside [0,1] raises ValueError.

Divisions only ever use `max_value`, which validate() requires > 0, so
saturated or zero-range sensors come out as 0 or 1, never NaN.
Non-finite live taxels are NOT repaired: they become NaN and the frame is
flagged False in `finite_mask` (the ingest drops and counts such frames).

Out-of-range raw values (outside [0, max_value] in raw units, live finite
taxels only) are counted per frame by `out_of_range`; what happens to them
(clip, drop the frame, fail) is the pipeline's `[normalise] out_of_range`
policy, applied by the ingest (htdata.ingest.episode).

Noise floor: a per-taxel baseline alone leaves raw-count gloves (e.g. 10-bit
counts ~490..1022) showing small non-zero values on every taxel while the
hands rest: sensor noise around the baseline reads as contact everywhere.
`noise_k` sets a per-taxel floor of k robust standard deviations
(1.4826 * MAD) of the rest window (needs baseline = "rest_window"), and
`noise_floor` a constant one in unit values; values up to the floor read 0.

Streaming: the baseline (and floor) is fitted once on the first chunk
(`fit_baseline`), then `apply` is called chunk by chunk with the same result
as on the whole. `fitted()` / `restore()` carry the fitted arrays into the
episode record and back (htdata.calibration), so the stored raw rows can be
renormalised later without the first chunk.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

CONVENTIONS = ("inverted", "direct")
BASELINES = ("none", "first_frame", "rest_window")


@dataclass
class NormaliseConfig:
    convention: str = "direct"
    max_value: float = 1.0
    baseline: str = "none"
    rest_frames: int = 10     # frames averaged (median) for baseline="rest_window"
    clip: bool = True
    scale: float = 1.0
    noise_floor: float = 0.0  # constant floor in unit values (after the baseline)
    noise_k: float = 0.0      # + k x robust spread of the rest window, per taxel

    @property
    def fits(self) -> bool:
        """True when the calibration has per-episode fitted arrays (baseline / noise floor)."""
        return self.baseline != "none" or self.noise_k > 0

    def validate(self, where: str = "normalise") -> "NormaliseConfig":
        if self.convention not in CONVENTIONS:
            raise ValueError(f"{where}: convention must be one of {CONVENTIONS}, got {self.convention!r}")
        if not (isinstance(self.max_value, (int, float)) and np.isfinite(self.max_value)
                and self.max_value > 0):
            raise ValueError(f"{where}: max_value must be a finite number > 0, got {self.max_value!r}")
        if self.baseline not in BASELINES:
            raise ValueError(f"{where}: baseline must be one of {BASELINES}, got {self.baseline!r}")
        if not isinstance(self.rest_frames, int) or self.rest_frames < 1:
            raise ValueError(f"{where}: rest_frames must be an integer >= 1, got {self.rest_frames!r}")
        if not (isinstance(self.scale, (int, float)) and np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"{where}: scale must be a finite number > 0, got {self.scale!r}")
        if not isinstance(self.clip, bool):
            raise ValueError(f"{where}: clip must be true or false, got {self.clip!r}")
        for name in ("noise_floor", "noise_k"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
                    and 0 <= value):
                raise ValueError(f"{where}: {name} must be a finite number >= 0, got {value!r}")
        if self.noise_floor >= 1:
            raise ValueError(f"{where}: noise_floor must be < 1 (unit values), got {self.noise_floor!r}")
        if self.noise_k > 0 and self.baseline != "rest_window":
            raise ValueError(f"{where}: noise_k needs baseline = \"rest_window\" (the floor is k x the rest "
                             f"window's spread), got baseline = {self.baseline!r}")
        return self

    @classmethod
    def from_layout_value(cls, value: dict) -> "NormaliseConfig":
        """Default config from a layout's `value` block ({"convention", "max"})."""
        return cls(convention=value["convention"], max_value=float(value["max"])).validate()

    def to_dict(self) -> dict:
        return asdict(self)


class Normaliser:
    """Apply a NormaliseConfig to raw grids (T,H,W) of one glove layout."""

    def __init__(self, cfg: NormaliseConfig, layout):
        self.cfg = cfg.validate()
        self.live_mask = np.asarray(layout.live_mask, dtype=bool)
        self.grid = tuple(self.live_mask.shape)
        self.layout_id = getattr(layout, "layout_id", "?")
        self.baseline: np.ndarray | None = None
        self.floor = np.full(self.grid, cfg.noise_floor, dtype=np.float32)
        if cfg.baseline == "none":
            self.baseline = np.zeros(self.grid, dtype=np.float32)

    def _check(self, raw) -> np.ndarray:
        arr = np.asarray(raw, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[1:] != self.grid:
            raise ValueError(f"layout {self.layout_id}: expected raw grids (T,{self.grid[0]},"
                             f"{self.grid[1]}), got shape {arr.shape}")
        return arr

    def to_unit(self, raw: np.ndarray) -> np.ndarray:
        """Convention + max only (before baseline/scale/clip)."""
        with np.errstate(invalid="ignore", over="ignore"):
            if self.cfg.convention == "inverted":
                return (np.float32(self.cfg.max_value) - raw) / np.float32(self.cfg.max_value)
            return raw / np.float32(self.cfg.max_value)

    def out_of_range(self, raw) -> tuple[np.ndarray, np.ndarray]:
        """(below, above): per frame, how many live finite taxels of `raw` lie below 0 / above max_value."""
        live = self._check(raw)[:, self.live_mask]
        with np.errstate(invalid="ignore"):
            below = (live < 0.0).sum(axis=1)
            above = (live > np.float32(self.cfg.max_value)).sum(axis=1)
        return below.astype(np.int64), above.astype(np.int64)

    def fit_baseline(self, first_chunk) -> np.ndarray:
        """Fix the per-taxel baseline from the episode's first frames (idempotent per episode)."""
        if self.cfg.baseline == "none":
            return self.baseline
        unit = self.to_unit(self._check(first_chunk))
        if unit.shape[0] == 0:
            raise ValueError(f"layout {self.layout_id}: cannot fit a baseline on zero frames")
        window = unit[:1] if self.cfg.baseline == "first_frame" else unit[: self.cfg.rest_frames]
        # Median over finite samples only; a taxel never finite in the window gets baseline 0.
        finite = np.isfinite(window)
        filled = np.where(finite, window, np.nan)
        n_finite = finite.sum(axis=0)
        base = np.zeros(self.grid, dtype=np.float32)
        has = n_finite > 0
        if has.any():
            base[has] = np.nanmedian(filled[:, has], axis=0)
        self.baseline = np.clip(base, 0.0, 1.0).astype(np.float32)
        if self.cfg.noise_k > 0:
            spread = np.zeros(self.grid, dtype=np.float32)
            if has.any():
                mad = np.nanmedian(np.abs(filled[:, has] - base[has]), axis=0)
                spread[has] = np.float32(1.4826) * mad
            self.floor = (np.float32(self.cfg.noise_floor)
                          + np.float32(self.cfg.noise_k) * spread).astype(np.float32)
        return self.baseline

    def fitted(self) -> dict[str, np.ndarray]:
        """The per-episode fitted arrays ({} when the config fits nothing): "baseline", "noise_floor"."""
        if not self.cfg.fits:
            return {}
        if self.baseline is None:
            raise RuntimeError(f"layout {self.layout_id}: nothing fitted yet")
        return {"baseline": self.baseline, "noise_floor": self.floor}

    def restore(self, fitted: dict[str, np.ndarray]) -> "Normaliser":
        """Set the arrays `fitted()` returned (an episode's calibration), instead of fitting them."""
        for name, arr in fitted.items():
            arr = np.asarray(arr, dtype=np.float32)
            if arr.shape != self.grid:
                raise ValueError(f"layout {self.layout_id}: fitted {name} has shape {arr.shape}, expected {self.grid}")
        if self.cfg.fits:
            missing = {"baseline", "noise_floor"} - set(fitted)
            if missing:
                raise ValueError(f"layout {self.layout_id}: fitted calibration lacks {sorted(missing)}")
            self.baseline = np.asarray(fitted["baseline"], dtype=np.float32)
            self.floor = np.asarray(fitted["noise_floor"], dtype=np.float32)
        return self

    def apply(self, raw) -> tuple[np.ndarray, np.ndarray]:
        """raw (T,H,W) -> (values (T,H,W) float32, finite_mask (T,) bool).

        Finite live taxels of values are in [0,1]; non-finite live taxels are
        set to NaN and their frame is False in finite_mask.
        """
        arr = self._check(raw)
        if self.baseline is None:
            raise RuntimeError(f"layout {self.layout_id}: fit_baseline() must be called before apply() "
                               f"with baseline={self.cfg.baseline!r}")
        finite_mask = np.isfinite(arr[:, self.live_mask]).all(axis=1)
        with np.errstate(invalid="ignore", over="ignore"):
            v = self.to_unit(arr)
            if self.cfg.baseline != "none":
                v = np.maximum(v - self.baseline, 0.0)
            if self.cfg.noise_k > 0 or self.cfg.noise_floor > 0:
                v = np.maximum(v - self.floor, 0.0)
            if self.cfg.scale != 1.0:
                v = v * np.float32(self.cfg.scale)
            if self.cfg.clip:
                v = np.clip(v, 0.0, 1.0)
            else:
                live = v[:, self.live_mask]
                bad = np.isfinite(live) & ((live < 0.0) | (live > 1.0))
                if bad.any():
                    t = int(np.argwhere(bad.any(axis=1))[0, 0])
                    raise ValueError(f"layout {self.layout_id}: frame {t} of this chunk has values outside "
                                     f"[0,1] after normalisation and clip=false "
                                     f"(min {np.nanmin(live[t]):.4g}, max {np.nanmax(live[t]):.4g})")
            # Clipping would turn +Inf into 1: mark every non-finite input NaN instead.
            v = np.where(np.isfinite(arr), v, np.float32(np.nan))
        return v.astype(np.float32, copy=False), finite_mask
