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

Noise floor: a baseline alone leaves raw-count gloves lit at rest (noise and
wander around it read as contact). `noise_k` sets a per-taxel floor of k
robust spreads (rest window, or the episode's rest: below), `noise_floor` a
constant one in unit values; values up to the floor read 0.
A layout of raw counts (value.max > 1, either direction: htdata.glove.glovevalue) without a [normalise.<id>]
table gets RAW_COUNT_DEFAULTS (each cell's 10th percentile per 60 s window + noise_k 5), not baseline "none";
an ingest holding 3 or more recordings of the glove gives it the glove's own rest instead (baseline "shift"
on a reference pooled over them: htdata.ingest.gloverest).

Streaming: fitted once (`fit_baseline`: first chunk; `fit_episode`), then `apply` chunk by chunk, same
as on the whole. `fitted()` / `restore()` carry the fitted arrays into the episode record and back
(htdata.glove.calibration): stored raw rows can be renormalised later.

The formula, in full (raw-count gloves, "direct": rest ~550, full scale 1023):

    v = clip(max(max(to_unit(raw) - baseline, 0) - floor, 0) * scale, 0, 1)
    to_unit(raw) = raw / max_value  (direct)  or  (max_value - raw) / max_value  (inverted)

`max_value` is the FULL-SCALE raw value (the ADC's top, the layout's
`value.max`), not the range above the baseline: a press from rest 550 to
1022 on a 1023 glove reads 0.46. Setting max_value to that range (472)
puts every raw value above it (all of them: rest is 550) out of range.

Fitting the baseline and noise floor (from the first frames, or on the whole episode for the
baselines chosen by activity: quietest, percentile, drift) is htdata.glove.baselinefit's job; the
settings (`NormaliseConfig`, its baselines and defaults) are htdata/glove/normaliseconfig.py.
"""

from __future__ import annotations

import numpy as np

from htdata._moved import moved_name
from htdata.errors import DatasetError
from htdata.glove.baselinefit import drift_baseline_at, fit_first_frames, fit_whole_episode
from htdata.glove.glovevalue import is_inverted, pressure_share
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.glove.restlevel import load_taxel_calibration


class Normaliser:
    """Apply a NormaliseConfig to raw grids (T,H,W) of one glove layout.

    Args:
        cfg: the layout's settings (validated here).
        layout: a glove.layouts.Layout (its live_mask, layout_id and value block's step).

    Raises:
        ConfigError: `cfg` is invalid (NormaliseConfig.validate), or its taxel calibration file does not
            read or fit the layout's grid (restlevel.load_taxel_calibration).
    """

    def __init__(self, cfg: NormaliseConfig, layout):
        self.cfg = cfg.validate()
        self.live_mask = np.asarray(layout.live_mask, dtype=bool)
        self.grid = tuple(self.live_mask.shape)
        self.layout_id = getattr(layout, "layout_id", "?")
        self.baseline: np.ndarray | None = None
        self.knot_rows: np.ndarray | None = None     # baseline="drift": row position of each knot
        step = (getattr(layout, "value", None) or {}).get("step")
        # a floor (when there is one) never lies below one quantisation step of the glove
        self.min_floor = (np.float32(float(step) / cfg.max_value)
                          if step and cfg.has_noise_floor else np.float32(0.0))
        self.floor = np.full(self.grid, max(cfg.noise_floor, self.min_floor), dtype=np.float32)
        if cfg.baseline == "none":
            self.baseline = np.zeros(self.grid, dtype=np.float32)
        self.offset: np.ndarray | None = None     # per-glove calibration file (raw units) and gain
        self.gain: np.ndarray | None = None
        if cfg.taxel_calibration:
            self.offset, self.gain = load_taxel_calibration(cfg.taxel_calibration, self.grid, self.layout_id)

    def _check(self, raw) -> np.ndarray:
        arr = np.asarray(raw, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[1:] != self.grid:
            raise ValueError(f"layout {self.layout_id}: expected raw grids (T,{self.grid[0]},"
                             f"{self.grid[1]}), got shape {arr.shape}")
        return arr

    def to_unit(self, raw: np.ndarray) -> np.ndarray:
        """Convention + max (+ the calibration file's per-taxel offset and gain), before baseline/scale/clip.

        Args:
            raw: (T,H,W) raw grids.

        Returns:
            (T,H,W) float32 unit values, not yet clipped.

        Raises:
            RuntimeError: the config names a taxel calibration whose arrays are not loaded (restore()).
        """
        if self.cfg.taxel_calibration_sha256 and self.offset is None:
            raise RuntimeError(f"layout {self.layout_id}: the taxel calibration file is not loaded (restore())")
        with np.errstate(invalid="ignore", over="ignore"):
            top = np.float32(self.cfg.max_value)
            if self.offset is not None:       # rest reads 0, a taxel's press counts by its own sensitivity
                above = (self.offset - raw) if is_inverted(self.cfg.convention) else (raw - self.offset)
                return above * self.gain / top
            return pressure_share(raw, self.cfg.convention, top)

    def out_of_range(self, raw) -> tuple[np.ndarray, np.ndarray]:
        """Per frame, how many live finite taxels of `raw` lie below 0 / above max_value (raw units).

        Args:
            raw: (T,H,W) raw grids.

        Returns:
            (below, above), each (T,) int64.
        """
        live = self._check(raw)[:, self.live_mask]
        with np.errstate(invalid="ignore"):
            below = (live < 0.0).sum(axis=1)
            above = (live > np.float32(self.cfg.max_value)).sum(axis=1)
        return below.astype(np.int64), above.astype(np.int64)

    def fit_baseline(self, first_chunk) -> np.ndarray:
        """Fix the per-taxel baseline from the episode's first frames (idempotent per episode).

        Args:
            first_chunk: (T,H,W) raw grids, the episode's first rows.

        Returns:
            The (H,W) baseline (the fitted one, for baselines fitted on the whole episode).

        Raises:
            RuntimeError: a whole-episode baseline not fitted yet (fit_episode first).
            ValueError: zero frames, or grids of another shape.
        """
        if self.cfg.baseline == "none":
            return self.baseline
        if self.cfg.per_episode:
            if self.baseline is None:
                raise RuntimeError(f"layout {self.layout_id}: baseline={self.cfg.baseline!r} is fitted on the "
                                   f"whole episode: call fit_episode() first")
            return self.baseline
        unit = self.to_unit(self._check(first_chunk))
        if unit.shape[0] == 0:
            raise ValueError(f"layout {self.layout_id}: cannot fit a baseline on zero frames")
        self.baseline, floor = fit_first_frames(unit, self.cfg, self.min_floor)
        if floor is not None:
            self.floor = floor
        return self.baseline

    def fit_episode(self, raw, fps: float, rows=None) -> np.ndarray:
        """Fit baseline="quietest" / "percentile" / "drift" (and the noise floor) on a whole episode's rows.

        Args:
            raw: (T,H,W) the episode's rows in time order.
            fps: the rows' rate (windows in seconds become rows).
            rows: their positions (default 0..T-1, the positions `apply(rows=)` gets for drift).

        Returns:
            The baseline: (H,W), or (K,H,W) knots for a knotted baseline.

        Raises:
            ValueError: zero frames, fps not > 0, or grids of another shape.
        """
        if not self.cfg.per_episode:
            return self.fit_baseline(raw)
        unit = self.to_unit(self._check(raw))
        T = unit.shape[0]
        if T == 0:
            raise ValueError(f"layout {self.layout_id}: cannot fit a baseline on zero frames")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"layout {self.layout_id}: fit_episode needs fps > 0, got {fps!r}")
        rows = np.arange(T) if rows is None else np.asarray(rows, np.int64)
        self.baseline, self.knot_rows, floor = fit_whole_episode(unit, rows, fps, self.cfg, self.live_mask,
                                                                 self.min_floor)
        if floor is not None:
            self.floor = floor
        return self.baseline

    def baseline_at(self, rows) -> np.ndarray:
        """The drift baseline at raw row positions (linear between knots, continued past the ends).

        Args:
            rows: (T,) row positions.

        Returns:
            (T,H,W) float32 baselines.
        """
        return drift_baseline_at(self.baseline, self.knot_rows, rows)

    def fitted(self) -> dict[str, np.ndarray]:
        """The per-episode fitted arrays, what an episode's calibration record carries.

        Returns:
            {"baseline", "noise_floor"} (+ "knot_rows" when knotted, "offset" and "gain" with a calibration
            file); {} when the config fits nothing.

        Raises:
            RuntimeError: nothing fitted yet.
        """
        if not self.cfg.fits:
            return {}
        if self.baseline is None:
            raise RuntimeError(f"layout {self.layout_id}: nothing fitted yet")
        out = {"baseline": self.baseline, "noise_floor": self.floor}
        if self.cfg.knotted:
            out["knot_rows"] = self.knot_rows
        if self.offset is not None:
            out["offset"], out["gain"] = self.offset, self.gain
        return out

    def restore(self, fitted: dict[str, np.ndarray]) -> "Normaliser":
        """Set the arrays `fitted()` returned (an episode's calibration), instead of fitting them.

        Args:
            fitted: name -> array, as `fitted()` returned them (read back from a dataset).

        Returns:
            self.

        Raises:
            DatasetError: an array of the wrong shape, a missing one, or knots and knot rows that disagree.
        """
        for name, arr in fitted.items():
            arr = np.asarray(arr, dtype=np.float32)
            if name == "knot_rows" or (name == "baseline" and self.cfg.knotted):
                continue     # knots (K,H,W) and their rows (K,): checked below
            if arr.shape != self.grid:
                raise DatasetError(f"layout {self.layout_id}: fitted {name} has shape {arr.shape}, expected {self.grid}")
        if self.cfg.fits:
            missing = {"baseline", "noise_floor"} - set(fitted)
            if missing:
                raise DatasetError(f"layout {self.layout_id}: fitted calibration lacks {sorted(missing)}")
            self.baseline = np.asarray(fitted["baseline"], dtype=np.float32)
            self.floor = np.asarray(fitted["noise_floor"], dtype=np.float32)
            if self.cfg.taxel_calibration_sha256:
                if "offset" not in fitted or "gain" not in fitted:
                    raise DatasetError(f"layout {self.layout_id}: fitted calibration lacks the taxel calibration "
                                       f"(offset, gain)")
                self.offset = np.asarray(fitted["offset"], np.float32)
                self.gain = np.asarray(fitted["gain"], np.float32)
            if self.cfg.knotted:
                knots = self.baseline.reshape(-1, *self.grid)
                rows = np.asarray(fitted.get("knot_rows", []), np.float32).reshape(-1)
                if len(rows) != len(knots) or len(rows) == 0:
                    raise DatasetError(f"layout {self.layout_id}: drift baseline has {len(knots)} knots and "
                                       f"{len(rows)} knot rows")
                self.baseline, self.knot_rows = knots, rows
        return self

    def apply(self, raw, rows=None) -> tuple[np.ndarray, np.ndarray]:
        """raw (T,H,W) -> (values (T,H,W) float32, finite_mask (T,) bool).

        Finite live taxels of values are in [0,1]; non-finite live taxels are
        set to NaN and their frame is False in finite_mask.

        Args:
            raw: (T,H,W) raw grids, a chunk of the episode.
            rows: the raw rows' positions in the episode (needed by knotted baselines only).

        Returns:
            (values (T,H,W) float32, finite_mask (T,) bool).

        Raises:
            ValueError: rows missing or of another length (knotted baselines), grids of another shape, or
                with clip=false a finite value outside [0,1].
            RuntimeError: the baseline is not fitted yet.
        """
        arr = self._check(raw)
        if self.cfg.knotted and self.baseline is not None:
            if rows is None:
                raise ValueError(f"layout {self.layout_id}: baseline=\"drift\" needs the raw rows' positions "
                                 f"(apply(raw, rows=...))")
            if len(rows) != len(arr):
                raise ValueError(f"layout {self.layout_id}: {len(rows)} row positions for {len(arr)} rows")
        if self.baseline is None:
            raise RuntimeError(f"layout {self.layout_id}: fit_baseline() must be called before apply() "
                               f"with baseline={self.cfg.baseline!r}")
        finite_mask = np.isfinite(arr[:, self.live_mask]).all(axis=1)
        with np.errstate(invalid="ignore", over="ignore"):
            v = self.to_unit(arr)
            if self.cfg.knotted:
                v = np.maximum(v - self.baseline_at(rows), 0.0)
            elif self.cfg.baseline != "none":
                v = np.maximum(v - self.baseline, 0.0)
            if self.cfg.has_noise_floor:
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


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
