"""Which raw cells move: per-cell activity over a recording, and the rule that calls a cell "moving".

A cell outside every block of a layout is never drawn. When its values move
during a recording it is almost always a sensor the layout forgot, so the
ingest reports it (episode record `unmapped_moving`, reports/ingest.json,
stderr) and `htdata layouts check LAYOUT --against RECORDING` lists it. Cells a
layout declares in `unused_cells` (and bend cells) are never reported.

Activity is accumulated over chunks of raw rows (T,H,W), in the glove's own
units, before any normalisation (`CellActivity.add`):

- range     = max - min of the cell's finite values over the recording;
- noise     = the cell's frame-to-frame noise from second differences,
              mean |x[t] - 2 x[t-1] + x[t-2]| * sqrt(pi / 12) (for white
              Gaussian noise of std s the second difference has std
              sqrt(6) s and mean absolute value s * sqrt(12 / pi), so this is
              s); differences ignore per-taxel offsets and slow drift, and a
              second difference also ignores smooth pressing and releasing
              (only the sharp corners of a press add to it).
- the GLOVE's noise = the median of the cell noise over reference cells: the
  layout's live cells (ingest, check), or every cell with finite values when
  there is no layout yet (suggest). Most cells rest most of the time, so the
  median is the resting noise.

The rule: a cell MOVES when its range > threshold, where

    threshold = max(MOVING_K * glove noise, MOVING_MIN_STEPS * value.step)

(`value.step` = the layout's quantisation step, 0 when the layout does not
state it). MOVING_K = 12: the range of white noise over 18,000 frames (10
minutes at 30 fps) is about 9 noise stds, so resting noise stays below it,
while a pressed knit-glove cell moves by hundreds of counts over a noise of
a few. MOVING_MIN_STEPS = 4 keeps a cell flickering between a few adjacent
quantisation levels quiet when the measured noise is below one step. On
noiseless data (threshold 0) any change moves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MOVING_K = 12.0
MOVING_MIN_STEPS = 4.0
_NOISE_FROM_ABS_DIFF2 = math.sqrt(math.pi / 12.0)


class CellActivity:
    """Streaming per-cell statistics of raw rows: finite count, min, max, mean |second difference|."""

    def __init__(self, grid: tuple[int, int]):
        self.grid = tuple(int(v) for v in grid)
        self.frames = 0
        self.count = np.zeros(self.grid, np.int64)
        self.lo = np.full(self.grid, np.inf, np.float64)
        self.hi = np.full(self.grid, -np.inf, np.float64)
        self.abs_diff = np.zeros(self.grid, np.float64)
        self.diffs = np.zeros(self.grid, np.int64)
        self._tail = np.zeros((0, *self.grid), np.float32)   # the last two rows seen (differences span chunks)

    def add(self, rows: np.ndarray) -> None:
        """Fold in consecutive raw rows (T,H,W) (any float or int dtype; NaN/Inf cells are skipped)."""
        x = np.asarray(rows, dtype=np.float32)
        if x.ndim != 3 or x.shape[1:] != self.grid:
            raise ValueError(f"activity: expected rows (T,{self.grid[0]},{self.grid[1]}), got {x.shape}")
        if not len(x):
            return
        finite = np.isfinite(x)
        self.frames += len(x)
        self.count += finite.sum(axis=0)
        np.minimum(self.lo, np.where(finite, x, np.inf).min(axis=0), out=self.lo)
        np.maximum(self.hi, np.where(finite, x, -np.inf).max(axis=0), out=self.hi)
        seq = np.concatenate([self._tail, x]) if len(self._tail) else x
        with np.errstate(invalid="ignore"):
            d = np.abs(seq[2:] - 2 * seq[1:-1] + seq[:-2]) if len(seq) > 2 else np.zeros((0, *self.grid), np.float32)
        ok = np.isfinite(d)
        self.abs_diff += np.where(ok, d, 0.0).sum(axis=0, dtype=np.float64)
        self.diffs += ok.sum(axis=0)
        self._tail = seq[-2:].copy()

    @property
    def range(self) -> np.ndarray:
        """(H,W) max - min of each cell's finite values (0 for a cell never finite)."""
        return np.where(self.count > 0, self.hi - self.lo, 0.0)

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


def moving_threshold(noise: float, step: float | None) -> float:
    """Range above which a cell moves (module docstring), in raw units."""
    return max(MOVING_K * float(noise), MOVING_MIN_STEPS * float(step or 0.0))


@dataclass(frozen=True)
class MovingCells:
    """Cells of a mask whose range exceeds the threshold, most active first."""

    cells: np.ndarray      # (N,2) int raw (row, col)
    ranges: np.ndarray     # (N,) raw units
    noise: float
    threshold: float
    frames: int

    def __len__(self) -> int:
        return len(self.cells)

    def record(self) -> dict:
        """The episode record's / report's entry (schemas/episode.schema.json `unmapped_moving`)."""
        return {"count": len(self), "cells": self.cells.tolist(),
                "range": [round(float(v), 4) for v in self.ranges],
                "noise": round(self.noise, 6), "threshold": round(self.threshold, 6), "frames": self.frames}


def moving_cells(activity: CellActivity, mask: np.ndarray, noise: float, step: float | None) -> MovingCells:
    """The cells of `mask` that move (range > moving_threshold(noise, step)), largest range first."""
    thr = moving_threshold(noise, step)
    rng = activity.range
    hit = np.asarray(mask, bool) & (rng > thr)
    cells = np.argwhere(hit)
    ranges = rng[hit]     # row-major, like argwhere
    order = np.lexsort((cells[:, 1], cells[:, 0], -ranges)) if len(cells) else np.zeros(0, np.int64)
    return MovingCells(cells=cells[order].astype(np.int64), ranges=ranges[order].astype(np.float64),
                       noise=float(noise), threshold=thr, frames=activity.frames)


def unmapped_moving(activity: CellActivity, layout) -> MovingCells:
    """Cells outside every block (not bend, not unused) that move, measured against the layout's live cells."""
    return moving_cells(activity, layout.unmapped_mask, activity.noise(layout.live_mask), layout.value.get("step"))


def describe_cells(cells, ranges, limit: int = 12) -> str:
    """"[r, c] range, ..." for the first `limit` cells, with how many more."""
    items = [f"[{int(r)}, {int(c)}] {float(v):.4g}" for (r, c), v in zip(list(cells)[:limit], list(ranges)[:limit])]
    more = len(cells) - limit
    return ", ".join(items) + (f", ... {more} more" if more > 0 else "")


def unmapped_warning(where: str, hand: str, layout_id: str, entry: dict) -> str:
    """One stderr line for an episode hand's unmapped moving cells (an episode record's entry)."""
    return (f"warning: {where}: {hand} hand (layout {layout_id}): {entry['count']} cell(s) outside every block "
            f"move (range > {entry['threshold']:.4g} raw units = max({MOVING_K:g} x noise {entry['noise']:.4g}, "
            f"{MOVING_MIN_STEPS:g} x step)) and are not drawn: {describe_cells(entry['cells'], entry['range'])}; "
            f"add them to a block, or list them in the layout's unused_cells")
