"""The glove's common mode: the slow wander every cell shares, taken out before a cell's own movement is judged.

A glove's rest level drifts as a whole (issue 43: a glove whose every cell
rises 6 counts over a clip): read cell by cell, that drift adds to every
cell's range and to the rest wander the moving-cell threshold is built from
(htdata.glove.activity), so a weakly pressed taxel (~15 counts on the real
left glove) falls under a bar that the drift raised by 3 x 6 counts. The
common mode is measured on the block means CellActivity keeps (WANDER_BLOCK
frames each; a glove's common wander is slow) and on the CALMEST cells only:

- each cell's level in a block = its block mean less its own low
  level (10th percentile of its block means: per-taxel offsets out);
- the calm cells = the COMMON_SHARE of the grid's finite cells (taxels and
  gaps: every cell wanders with the glove) whose block means range least
  over the recording, the common mode found so far taken out (COMMON_PASSES
  times: ranked on raw ranges, a drift favours the cells that wander against
  it): cells that were not pressed and are not cross-talk. A press may cover
  most of a layout's live cells (a palm and two strips gripped at once: 2/3
  of a 16x16 grid), so a median over every cell would follow the press,
  while the calmest quarter still rests;
- the common mode of a block = the median of the calm cells' levels in it.

`steady` gives each cell's min / max (per block and over the rows after the
last full block: its lowest and highest value, less the common mode at that
frame, `frame_common`: linear between block centres, so a drift of 6 counts
over a 135-frame clip leaves no 0.7-count step per block) and block means
less the common mode: what the moving-cell rule reads. Without two full
blocks there is no wander to take out and the values are the raw ones.
`rows_common_mode` gives the common mode at every row of a recording read
whole: the glove's rest reference takes it out before each cell's rest is
read (htdata.glove.restreference.recording_rest).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from htdata.glove.restlevel import nanpercentile_columns

COMMON_SHARE = 0.25      # the calmest quarter of the reference cells carries the glove's common mode
COMMON_PASSES = 3        # calm again with the common mode found so far taken out (a drift favours cells against it)


@dataclass(frozen=True)
class Steady:
    """A recording's per-cell statistics with the glove's common mode taken out (module docstring)."""

    lo: np.ndarray        # (H,W) least value less its block's common mode (+inf: never finite)
    hi: np.ndarray        # (H,W) largest value less its block's common mode (-inf: never finite)
    blocks: np.ndarray    # (blocks, H*W) float64 block means less their common mode
    common: np.ndarray    # (blocks,) the common mode of each block (0 without two blocks)

    @property
    def range(self) -> np.ndarray:
        """(H,W) hi - lo (0 for a cell never finite)."""
        return np.where(np.isfinite(self.lo) & np.isfinite(self.hi), self.hi - self.lo, 0.0)


def block_common_mode(means: np.ndarray) -> np.ndarray:
    """(blocks,) the common mode of each block (module docstring), read on every cell with a finite value.

    Args:
        means: (blocks, cells) float64 block means of every cell (NaN where a cell had no finite value).
    """
    if len(means) < 2:
        return np.zeros(len(means))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # a cell never finite: NaN, left out
        ref = np.isfinite(means).any(axis=0)
        if not ref.any():
            return np.zeros(len(means))
        m = means[:, ref]
        level = m - nanpercentile_columns(m, 10)
        common = np.zeros(len(m))
        for _ in range(COMMON_PASSES):
            left = m - common[:, None]
            spread = np.nanmax(left, axis=0) - np.nanmin(left, axis=0)
            calm = np.argsort(spread, kind="stable")[:max(1, math.ceil(COMMON_SHARE * m.shape[1]))]
            common = nanpercentile_columns(level[:, calm].T, 50)
            common = np.where(np.isfinite(common), common, 0.0)
    return common


def frame_common(common: np.ndarray, frames: np.ndarray, block: int) -> np.ndarray:
    """The common mode at each of `frames` (recording frame indices): linear between block centres, and on from the
    first / last two beyond them (a drift goes on through the half blocks at either end and the rows after the
    last full block).

    Args:
        common: (blocks,) the common mode of each block (`block_common_mode`).
        frames: int array of frame indices (any shape).
        block: frames per block (htdata.glove.activity.WANDER_BLOCK).
    """
    f = np.asarray(frames, np.float64)
    if len(common) < 2:
        return np.zeros(f.shape)
    centres = np.arange(len(common)) * block + (block - 1) / 2.0
    out = np.interp(f, centres, common)
    first, last = (common[1] - common[0]) / block, (common[-1] - common[-2]) / block
    out = np.where(f < centres[0], common[0] + (f - centres[0]) * first, out)
    return np.where(f > centres[-1], common[-1] + (f - centres[-1]) * last, out)


def rows_common_mode(rows: np.ndarray, block: int) -> np.ndarray:
    """(T,) the common mode at each of a recording's rows, from the means of its full blocks of `block` rows
    (`block_common_mode`, `frame_common`); zeros without two full blocks.

    Args:
        rows: (T, cells) raw rows turned toward pressure (NaN: no value).
        block: rows per block mean (htdata.glove.activity.WANDER_BLOCK).
    """
    x = np.asarray(rows, np.float64)
    n = len(x) // block
    if n < 2:
        return np.zeros(len(x))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # a cell never finite in a block: NaN, left out
        means = np.nanmean(x[:n * block].reshape(n, block, -1), axis=1)
    return frame_common(block_common_mode(means), np.arange(len(x)), block)


def steady(means: np.ndarray, lo: tuple[np.ndarray, np.ndarray], hi: tuple[np.ndarray, np.ndarray],
           block: int) -> Steady:
    """Per-cell min / max and block means with the glove's common mode taken out.

    Args:
        means: (blocks, cells) float64 block means.
        lo: (values, frames): (parts, cells) each cell's least finite value in each block and in the rows after
            the last full block (+inf: none), and the frame where it was read.
        hi: (values, frames): the same for the largest value (-inf: none).
        block: frames per block (htdata.glove.activity.WANDER_BLOCK).
    """
    common = block_common_mode(means)
    with np.errstate(invalid="ignore"):
        least = np.min(lo[0] - frame_common(common, lo[1], block), axis=0, initial=np.inf)
        most = np.max(hi[0] - frame_common(common, hi[1], block), axis=0, initial=-np.inf)
    return Steady(least, most, means - common[:, None], common)


def block_extremes(blocks: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """((least, rows), (largest, rows)), each array (blocks, H, W): every cell's least and largest finite value
    in each block and the row of the block where it was read (+-inf and row 0: none finite).

    Args:
        blocks: (blocks, rows per block, H, W) raw rows.
    """
    finite = np.isfinite(blocks)
    every = finite.all()            # the usual case: no copy, and one finiteness pass for both ends
    small = np.uint8 if blocks.shape[1] <= 256 else np.int64          # a row of a block: one byte a cell kept
    out = []
    for highest in (False, True):
        y = blocks if every else np.where(finite, blocks, -np.inf if highest else np.inf)
        k = y.argmax(axis=1) if highest else y.argmin(axis=1)
        out.append((np.take_along_axis(y, k[:, None], axis=1)[:, 0], k.astype(small)))
    return out[0], out[1]


def steady_of(means: list[np.ndarray], lo: tuple[list, list], hi: tuple[list, list], rows: np.ndarray,
              block: int) -> Steady:
    """`steady` of a CellActivity's kept statistics, (H,W)-shaped.

    Args:
        means: (H,W) block means, one per full block.
        lo: (values, rows) lists of `block_extremes` arrays, one per full block (least values).
        hi: the same for the largest values.
        rows: (T,H,W) the rows after the last full block.
        block: frames per block (htdata.glove.activity.WANDER_BLOCK).
    """
    grid = rows.shape[1:]
    cells = int(np.prod(grid))

    def stack(xs: list) -> np.ndarray:
        return np.stack(xs).reshape(len(xs), -1) if xs else np.zeros((0, cells))
    parts = []
    first = np.arange(len(means) + 1)[:, None] * block                  # each block's first frame, then the rows'
    tail = block_extremes(rows[None]) if len(rows) else None      # the rows after the last full block
    for highest, (vals, at) in enumerate((lo, hi)):
        v, k = tail[highest] if tail is not None else (
            np.full((1, *grid), -np.inf if highest else np.inf), np.zeros((1, *grid), np.int64))
        parts.append((np.vstack([stack(vals).astype(np.float64), v.reshape(1, -1)]),
                      first + np.vstack([stack(at).astype(np.int64), k.reshape(1, -1).astype(np.int64)])))
    st = steady(stack(means).astype(np.float64), parts[0], parts[1], block)
    return Steady(st.lo.reshape(grid), st.hi.reshape(grid), st.blocks, st.common)
