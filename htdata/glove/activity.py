"""Which raw cells move: per-cell activity over a recording, and the rule that calls a cell "moving".

A cell outside every block of a layout is never drawn. When its values rise
during a recording it is almost always a sensor the layout forgot, so the
ingest reports it (episode record `unmapped_moving`, reports/ingest.json,
stderr) and `htdata layouts check LAYOUT --against RECORDING` lists it; a
cell that only falls below its rest is cross-talk and is listed apart. Cells a
layout declares in `unused_cells` (and bend cells) are never reported.

Activity is accumulated over chunks of raw rows (T,H,W), in the glove's own
units, before any normalisation (`CellActivity.add`):

- range     = max - min of the cell's finite values over the recording;
- noise     = the cell's FAST (frame-to-frame) noise from second differences,
              mean |x[t] - 2 x[t-1] + x[t-2]| * sqrt(pi / 12) (for white
              Gaussian noise of std s the second difference has std
              sqrt(6) s and mean absolute value s * sqrt(12 / pi), so this is
              s); differences ignore per-taxel offsets and slow drift, and a
              second difference also ignores smooth pressing and releasing.
- wander    = the cell's SLOW rest wander: the range of its means over
              blocks of WANDER_BLOCK frames (fast noise averages out) taken
              over its QUIET blocks only: up to its 10th percentile +
              WANDER_QUIET_K robust spreads of its lower half. A press only
              raises a cell, so its presses are left out even when it is held
              for most of the recording (the lower half still rests).
- the GLOVE's noise and wander = the medians of the cell values over
  reference cells: the layout's live cells (ingest, check, health), or every
  cell with finite values when there is no layout yet (suggest). Most cells
  rest most of the time, so the medians are the resting values; a cell's
  own wander is never its threshold (a forgotten sensor pressed now and then
  would set its own bar).

Real knit gloves need both: their cells wander slowly at rest (a median 5
counts over a clip, p90 6-7) with a fast noise of only 0.15 counts, so a
threshold from the fast noise alone (12 x 0.15 = 1.8 counts) called every
cell of the grid moving (issue 27), while pressed cells move 25-120 counts.
The rule: a cell MOVES when its range > threshold, where

    threshold = max(MOVING_K * glove noise + WANDER_K * glove wander,
                    MOVING_MIN_STEPS * value.step,
                    MOVING_MIN_FULL_SCALE * value.max)

(`value.step` = the layout's quantisation step, 0 when the layout does not
state it; `value.max` its full scale, 0 when there is no layout yet): a
resting cell's range is its slow wander plus its fast noise's range.
MOVING_K = 12: the range of white noise over 18,000 frames (10 minutes at
30 fps) is about 9 noise stds. WANDER_K = 3: the glove's median wander
measured on quiet blocks is short of a whole clip's and a cell's wander
varies (p90 / median ~1.4 on the real glove), so three medians clear the
resting cells. MOVING_MIN_STEPS = 4 keeps a cell flickering between a few
adjacent quantisation levels quiet. MOVING_MIN_FULL_SCALE = the contact
level (htdata.glove.contact.THRESHOLD, 0.02 of full scale, 20.5 counts of
1023): a cell outside every block that never moves by that much would never
read contact in a map, so it is no finding. It is the bar on SHORT clips,
where the wander measured is small (1.4-2 counts over 135-300 frames) while
resting cells still range 4-9 counts (the whole glove dips by ~5 counts for
a few frames, which half-second block means smooth away) and cells beside a
press or on a cross-talk column move 10-20 counts; on long clips of a noisy
glove the noise and wander term is the larger. On noiseless data without a
full scale (threshold 0) any change moves.

Range, wander and rest level are read with the GLOVE'S COMMON MODE taken
out (`CellActivity.steady`, htdata.glove.commonmode: per block, the median
level of the grid's calmest quarter of cells, linear between blocks): every
cell of a real glove wanders with the whole glove, and a drift of 6 counts
over a clip added 6 to every range and 3 x 6 to the threshold, so weakly
pressed taxels (~15 counts) stopped moving (issue 43, the drifting glove).

A moving cell is CROSS-TALK, not a sensor, when it only falls: it falls
below its rest by more than the threshold and never rises that far above it
(in the pressure direction: `inverted` gloves fall when pressed). Its rest
is its level while the glove rests (`CellActivity.rest_level`: its median
block mean over the REST_SHARE of blocks where the reference cells sit
nearest their own low level, the glove-wide shift of each block taken out):
a cell beside a press falls while the glove is pressed, so its own median
may be its fallen level, but the glove's quiet blocks show where it rests.
A cell that both rises and falls, or moves by neither alone, is counted as
rising (a finding to look at). The constants live here; ingest
(`unmapped_moving`), `htdata layouts check --against`, `htdata layouts
suggest` (without the full-scale floor: it looks for sensor areas, and a
lightly pressed taxel is one) and raw-row health
(htdata/glove/rawhealth.py) all use `moving_cells`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from htdata.glove.commonmode import Steady, block_extremes, steady_of
from htdata.glove.contact import THRESHOLD as CONTACT_THRESHOLD
from htdata.glove.glovevalue import is_inverted
from htdata.glove.restlevel import nanpercentile_columns

MOVING_K = 12.0          # x the glove's fast (second-difference) noise
WANDER_K = 3.0           # x the glove's slow rest wander (range of quiet block means)
MOVING_MIN_STEPS = 4.0   # x the quantisation step: the least a cell must move
WANDER_BLOCK = 16        # frames per block mean (half a second at 30 fps)
WANDER_QUIET_K = 6.0     # a cell's block is quiet up to its p10 + this many robust spreads of its lower half
MOVING_MIN_FULL_SCALE = CONTACT_THRESHOLD   # x full scale (value.max): the least a cell must move (contact level)
REST_SHARE = 0.10        # the glove's quietest share of blocks: where each cell's rest level is read
DIRECTION_RATIO = 2.0    # read one way, a glove's presses "only fall" in this many times more cells than read the
DIRECTION_MIN_CELLS = 8  # other way, and in at least this many cells (MIN_BLOCK_CELLS): else the direction is unclear
_NOISE_FROM_ABS_DIFF2 = math.sqrt(math.pi / 12.0)


class CellActivity:
    """Streaming per-cell statistics of raw rows: finite count, min, max, mean |second difference|,
    and the means of consecutive blocks of WANDER_BLOCK rows (for the slow wander)."""

    def __init__(self, grid: tuple[int, int]):
        self.grid = tuple(int(v) for v in grid)
        self.frames = 0
        self.count = np.zeros(self.grid, np.int64)
        self.lo = np.full(self.grid, np.inf, np.float64)
        self.hi = np.full(self.grid, -np.inf, np.float64)
        self.abs_diff = np.zeros(self.grid, np.float64)
        self.diffs = np.zeros(self.grid, np.int64)
        self._tail = np.zeros((0, *self.grid), np.float32)   # the last two rows seen (differences span chunks)
        self._blocks: list[np.ndarray] = []                   # (H,W) mean of each full block of rows
        self._block_lo: list[np.ndarray] = []                 # (H,W) least / largest finite value in each block
        self._block_hi: list[np.ndarray] = []
        self._steady: Steady | None = None                    # `steady`, until more rows come
        self._lo_at: list[np.ndarray] = []                    # (H,W) the row of each block where it was read
        self._hi_at: list[np.ndarray] = []
        self._open = np.zeros((0, *self.grid), np.float32)   # rows of the block not yet full

    def add(self, rows: np.ndarray) -> None:
        """Fold in consecutive raw rows (T,H,W) (any float or int dtype; NaN/Inf cells are skipped)."""
        x = np.asarray(rows, dtype=np.float32)
        if x.ndim != 3 or x.shape[1:] != self.grid:
            raise ValueError(f"activity: expected rows (T,{self.grid[0]},{self.grid[1]}), got {x.shape}")
        if not len(x):
            return
        finite = np.isfinite(x)
        self._steady = None
        self.frames += len(x)
        self.count += finite.sum(axis=0)
        np.minimum(self.lo, np.where(finite, x, np.inf).min(axis=0), out=self.lo)
        np.maximum(self.hi, np.where(finite, x, -np.inf).max(axis=0), out=self.hi)
        seq = np.concatenate([self._tail, x]) if len(self._tail) else x
        # a huge raw value (3e38 in float32) overflows to inf here and is left out by `ok` below: no warning
        with np.errstate(invalid="ignore", over="ignore"):
            d = np.abs(seq[2:] - 2 * seq[1:-1] + seq[:-2]) if len(seq) > 2 else np.zeros((0, *self.grid), np.float32)
        ok = np.isfinite(d)
        self.abs_diff += np.where(ok, d, 0.0).sum(axis=0, dtype=np.float64)
        self.diffs += ok.sum(axis=0)
        self._tail = seq[-2:].copy()
        self._add_blocks(x)

    def _add_blocks(self, x: np.ndarray) -> None:
        rows = np.concatenate([self._open, x]) if len(self._open) else x
        full = len(rows) // WANDER_BLOCK * WANDER_BLOCK
        if full:
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)      # a cell never finite in a block: NaN
                blocks = rows[:full].reshape(-1, WANDER_BLOCK, *self.grid)
                means = np.nanmean(blocks, axis=1)
            self._blocks.extend(means)
            for (vals, at), (v, k) in zip(((self._block_lo, self._lo_at), (self._block_hi, self._hi_at)),
                                          block_extremes(blocks), strict=True):
                vals.extend(v)
                at.extend(k)
        self._open = rows[full:].copy()

    def mirrored(self) -> "CellActivity":
        """The activity of the rows turned upside down (-rows): an inverted glove's rows in the pressure direction
        (glovevalue.toward_pressure, up to its offset `top`, which no moving-cell rule reads: they use ranges,
        noise and levels against the cell's own rest)."""
        out = CellActivity(self.grid)
        out.frames, out.count, out.abs_diff, out.diffs = self.frames, self.count.copy(), self.abs_diff.copy(), self.diffs.copy()
        out.lo, out.hi = -self.hi, -self.lo
        out._tail, out._open = -self._tail, -self._open
        out._blocks = [-b for b in self._blocks]
        out._block_lo, out._block_hi = [-b for b in self._block_hi], [-b for b in self._block_lo]
        out._lo_at, out._hi_at = list(self._hi_at), list(self._lo_at)
        return out

    @property
    def range(self) -> np.ndarray:
        """(H,W) max - min of each cell's finite values (0 for a cell never finite)."""
        return np.where(self.count > 0, self.hi - self.lo, 0.0)

    def steady(self) -> Steady:
        """Min / max and block means of each cell less the glove's common mode, read on every cell of the grid
        (htdata.glove.commonmode; taxels and gaps wander together, and a press may cover most of the live
        cells): what the moving-cell rule reads. Kept until more rows are added."""
        if self._steady is None:
            self._steady = steady_of(self._blocks, (self._block_lo, self._lo_at), (self._block_hi, self._hi_at),
                                     self._open, WANDER_BLOCK)
        return self._steady

    @property
    def cell_noise(self) -> np.ndarray:
        """(H,W) frame-to-frame noise of each cell (NaN without three consecutive finite values)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.diffs > 0, self.abs_diff / np.maximum(self.diffs, 1), np.nan) * _NOISE_FROM_ABS_DIFF2

    def noise(self, reference: np.ndarray | None = None) -> float:
        """The glove's noise: median cell noise over `reference` cells (every cell when None); 0 if none."""
        n = self.cell_noise
        sel = np.isfinite(n) if reference is None else (np.asarray(reference, bool) & np.isfinite(n))
        return float(np.median(n[sel])) if sel.any() else 0.0

    def cell_wander(self) -> np.ndarray:
        """(H,W) range of each cell's block means (less the glove's common mode, `steady`) over its quiet blocks
        (NaN without two; module docstring).

        Every cell at once (`nanpercentile_columns`: numpy's nan-percentiles loop over cells in Python).
        """
        if len(self._blocks) < 2:
            return np.full(self.grid, np.nan)
        b = self.steady().blocks
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # a cell never finite: NaN
            # rest = the cell's lower half (a press only raises a cell: held for most of a clip, it still
            # leaves the lower half to rest); quiet = up to its 10th percentile + K robust spreads of that half
            mid, p10 = nanpercentile_columns(b, [50, 10])
            low = np.where(b <= mid, b, np.nan)
            spread = 1.4826 * nanpercentile_columns(np.abs(low - nanpercentile_columns(low, 50)), 50)
            quiet = np.where(b <= p10 + WANDER_QUIET_K * spread, b, np.nan)
            out = np.nanmax(quiet, axis=0) - np.nanmin(quiet, axis=0)
        return out.reshape(self.grid)

    def wander(self, reference: np.ndarray | None = None) -> float:
        """The glove's slow rest wander: median cell wander over `reference` cells (every cell when None)."""
        w = self.cell_wander()
        sel = np.isfinite(w) if reference is None else (np.asarray(reference, bool) & np.isfinite(w))
        return float(np.median(w[sel])) if sel.any() else 0.0

    def rest_level(self, reference: np.ndarray | None = None) -> np.ndarray:
        """(H,W) each cell's level while the glove rests: its median block mean over the glove's quietest blocks.

        Quiet blocks = the REST_SHARE of blocks (at least one) where the `reference` cells (every finite cell
        when None) sit nearest their own low level (10th percentile of block means), after the glove-wide
        shift of that block (the reference cells' median) is taken out: a press raises some cells, cross-talk
        lowers others, a common-mode dip moves them all. NaN without a full block.
        """
        if not self._blocks:
            return np.full(self.grid, np.nan)
        b = self.steady().blocks
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # a cell never finite: NaN
            d = b - nanpercentile_columns(b, 10)
            ref = np.isfinite(d).any(axis=0)
            if reference is not None:
                ref &= np.asarray(reference, bool).reshape(-1)
            if not ref.any():
                ref = np.isfinite(d).any(axis=0)
            d = d[:, ref]
            shift = nanpercentile_columns(d.T, 50)              # (blocks,) glove-wide shift
            away = np.nanmean(np.abs(d - shift[:, None]), axis=1)
            away = np.where(np.isfinite(away), away, np.inf)
            quiet = np.argsort(away, kind="stable")[:max(1, math.ceil(REST_SHARE * len(b)))]
            rest = nanpercentile_columns(b[quiet], 50)
        return rest.reshape(self.grid)


def moving_threshold(noise: float, step: float | None, wander: float = 0.0, full_scale: float | None = None) -> float:
    """Range above which a cell moves (module docstring), in raw units."""
    return max(MOVING_K * float(noise) + WANDER_K * float(wander), MOVING_MIN_STEPS * float(step or 0.0),
               MOVING_MIN_FULL_SCALE * float(full_scale or 0.0))


def rule_text(full_scale: bool = True) -> str:
    """The rule in words, with its constants (stderr lines, layout notes, the health legend); `full_scale`
    False: without the contact floor (`layouts suggest`, where full scale is not known yet)."""
    floor = f", {MOVING_MIN_FULL_SCALE:g} x full scale" if full_scale else ""
    return f"range > max({MOVING_K:g} x fast noise + {WANDER_K:g} x rest wander, {MOVING_MIN_STEPS:g} x step{floor})"


@dataclass(frozen=True)
class MovingCells:
    """Cells of a mask whose range exceeds the threshold, most active first: `crosstalk` fall below their rest
    by more than the threshold and never rise that far above it; `cells` are the others (sensors)."""

    cells: np.ndarray      # (N,2) int raw (row, col): move, and not only by falling
    ranges: np.ndarray     # (N,) raw units
    noise: float
    threshold: float
    frames: int
    wander: float = 0.0
    crosstalk: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))   # (M,2): only fall
    crosstalk_ranges: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float64))   # (M,)

    def __len__(self) -> int:
        return len(self.cells)

    def record(self) -> dict:
        """The episode record's / report's entry (schemas/episode.schema.json `unmapped_moving`)."""
        out = {"count": len(self), "cells": self.cells.tolist(),
               "range": [round(float(v), 4) for v in self.ranges],
               "noise": round(self.noise, 6), "wander": round(self.wander, 6), "threshold": round(self.threshold, 6),
               "frames": self.frames}
        if len(self.crosstalk):
            out["crosstalk"] = {"count": len(self.crosstalk), "cells": self.crosstalk.tolist(),
                                "range": [round(float(v), 4) for v in self.crosstalk_ranges]}
        return out


def _by_range(cells: np.ndarray, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.lexsort((cells[:, 1], cells[:, 0], -ranges)) if len(cells) else np.zeros(0, np.int64)
    return cells[order].astype(np.int64).reshape(-1, 2), ranges[order].astype(np.float64)


def moving_cells(activity: CellActivity, mask: np.ndarray, reference: np.ndarray | None,
                 step: float | None, full_scale: float | None = None, inverted: bool = False) -> MovingCells:
    """The cells of `mask` that move, measured against the `reference` cells' noise and wander (None: every
    cell), largest range first; cells that only fall below their rest (`CellActivity.rest_level`; in the
    pressure direction: up when `inverted`) by more than the threshold are set apart as cross-talk."""
    noise, wander = activity.noise(reference), activity.wander(reference)
    thr = moving_threshold(noise, step, wander, full_scale)
    st = activity.steady()                  # the glove's common mode taken out (htdata.glove.commonmode)
    rng = st.range
    hit = np.asarray(mask, bool) & (rng > thr)
    rest = activity.rest_level(reference)
    with np.errstate(invalid="ignore"):
        rise = (rest - st.lo) if inverted else (st.hi - rest)
        fall = (st.hi - rest) if inverted else (rest - st.lo)
        # cross-talk: falls below its rest by more than the threshold and never rises that far above it (no rest
        # level, under one block of frames: NaN, never cross-talk); a cell moving by neither alone rises too
        only_falls = hit & (fall > thr) & ~(rise > thr)
    rises = hit & ~only_falls
    cells, ranges = _by_range(np.argwhere(rises), rng[rises])        # row-major, like argwhere
    xcells, xranges = _by_range(np.argwhere(only_falls), rng[only_falls])
    return MovingCells(cells=cells, ranges=ranges, noise=float(noise), threshold=thr, frames=activity.frames,
                       wander=float(wander), crosstalk=xcells, crosstalk_ranges=xranges)


@dataclass(frozen=True)
class SeenDirection:
    """Which way a glove's counts go with pressure, as recordings show it (`seen_direction`)."""

    inverted: bool | None      # None: the recordings do not tell
    falls_as_direct: int       # cells that only fall below rest when the counts are read as rising with pressure
    falls_as_inverted: int     # ... when read as falling with pressure

    def text(self) -> str:
        return (f"{self.falls_as_direct} cell(s) only fall below rest read as direct, {self.falls_as_inverted} read "
                f"as inverted")


def seen_direction(activities: list[CellActivity], step: float | None) -> SeenDirection:
    """The direction of a glove without a layout, from its recordings (each against its own noise and rest).

    Read in the wrong direction, every press "only falls" below its rest, like cross-talk; read in the right one,
    only the cells beside a press do. So the direction whose only-falling cells are DIRECTION_RATIO times fewer
    than the other's (which are at least DIRECTION_MIN_CELLS) is the glove's; otherwise it is unclear (a single
    recording gripped throughout can look either way).
    """
    def falls(acts: list[CellActivity]) -> int:
        return sum(len(moving_cells(a, np.ones(a.grid, bool), None, step).crosstalk) for a in acts)

    as_direct, as_inverted = falls(activities), falls([a.mirrored() for a in activities])
    inverted = None
    if max(as_direct, as_inverted) >= DIRECTION_MIN_CELLS:
        if as_inverted >= DIRECTION_RATIO * as_direct:
            inverted = False
        elif as_direct >= DIRECTION_RATIO * as_inverted:
            inverted = True
    return SeenDirection(inverted, as_direct, as_inverted)


def unmapped_moving(activity: CellActivity, layout) -> MovingCells:
    """Cells outside every block (not bend, not unused) that move, measured against the layout's live cells,
    with the layout's step, full scale (value.max) and direction (value.convention)."""
    return moving_cells(activity, layout.unmapped_mask, layout.live_mask, layout.value.get("step"),
                        full_scale=layout.value.get("max"), inverted=is_inverted(layout.value.get("convention")))


def live_moving(activity: CellActivity, layout) -> MovingCells:
    """The layout's live cells that move (rise, in its direction) by the one rule, against its live cells, with its
    step, full scale and direction: the taxels a recording pressed."""
    return moving_cells(activity, layout.live_mask, layout.live_mask, layout.value.get("step"),
                        full_scale=layout.value.get("max"), inverted=is_inverted(layout.value.get("convention")))


def describe_cells(cells, ranges, limit: int = 12) -> str:
    """"[r, c] range, ..." for the first `limit` cells, with how many more."""
    items = [f"[{int(r)}, {int(c)}] {float(v):.4g}" for (r, c), v in zip(list(cells)[:limit], list(ranges)[:limit])]
    more = len(cells) - limit
    return ", ".join(items) + (f", ... {more} more" if more > 0 else "")


def unmapped_warning(where: str, hand: str, layout_id: str, entry: dict) -> str:
    """One stderr line for an episode hand's unmapped moving cells (an episode record's entry)."""
    return (f"warning: {where}: {hand} hand (layout {layout_id}): {entry['count']} cell(s) outside every block "
            f"move (range > {entry['threshold']:.4g} raw units = max({MOVING_K:g} x noise {entry['noise']:.4g} + "
            f"{WANDER_K:g} x wander {entry.get('wander', 0.0):.4g}, {MOVING_MIN_STEPS:g} x step, "
            f"{MOVING_MIN_FULL_SCALE:g} x full scale)) and are not drawn: {describe_cells(entry['cells'], entry['range'])}; "
            f"add them to a block, or list them in the layout's unused_cells")
