"""A glove whose every cell drifts together (issue 43): weak presses still move, resting cells still rest.

Real knit gloves wander as a whole (../shared/real_glove/README.md): the bench's drifting glove adds a common
ramp of +6 counts over each clip. Read cell by cell, that ramp added 6 counts to every range and 3 x 6 to the
moving-cell threshold, so the left hand's weak presses (~15 counts) were lost to `layouts suggest`.
"""

from __future__ import annotations

import numpy as np

from htdata.glove.activity import CellActivity, moving_cells

GRID = (16, 16)
PATCH = (slice(4, 8), slice(4, 8))


def _drifting_glove(frames: int, drift: float, seed: int = 0) -> np.ndarray:
    """(T,16,16) counts: rest ~257 with per-cell offsets, a fast noise of 0.15 counts, each cell's own slow wander
    of ~1.5 counts, a common ramp of `drift` counts over the clip, and a weak press (+15 counts) of a 4x4 patch."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, frames)[:, None, None]
    own = rng.uniform(-1.5, 1.5, (1, *GRID)) * np.sin(2 * np.pi * (t + rng.uniform(0, 1, (1, *GRID))))
    x = 257 + rng.uniform(-20, 20, (1, *GRID)) + own + rng.normal(0, 0.15, (frames, *GRID)) + drift * t
    press = np.zeros(frames)
    press[frames // 3: frames // 3 + 60] = 15.0
    x[:, PATCH[0], PATCH[1]] += press[:, None, None]
    return np.asarray(x, np.float16).astype(np.float32)


def _moving(x: np.ndarray) -> set[tuple[int, int]]:
    act = CellActivity(GRID)
    for chunk in np.array_split(x, 3):                 # streamed in chunks, as ingest and suggest feed it
        act.add(chunk)
    return set(map(tuple, moving_cells(act, np.ones(GRID, bool), None, None).cells.tolist()))


def test_a_weak_press_moves_on_a_glove_that_drifts_as_a_whole():
    patch = {(r, c) for r in range(4, 8) for c in range(4, 8)}
    for frames in (150, 300, 900):                     # short clips drift steeply (6 counts in 5 s)
        steady, drifting = _moving(_drifting_glove(frames, 0.0)), _moving(_drifting_glove(frames, 6.0))
        assert steady == patch, (frames, sorted(steady ^ patch))
        assert drifting == patch, (frames, sorted(drifting ^ patch))


def test_a_falling_drift_is_taken_out_the_same_way():
    patch = {(r, c) for r in range(4, 8) for c in range(4, 8)}
    assert _moving(_drifting_glove(300, -6.0, seed=1)) == patch


def test_the_common_mode_is_the_same_streamed_in_chunks_or_in_one_pass():
    x = _drifting_glove(333, 6.0, seed=2)               # 20 full blocks and 13 rows after them
    whole, chunked = CellActivity(GRID), CellActivity(GRID)
    whole.add(x)
    for chunk in np.array_split(x, 7):
        chunked.add(chunk)
    a, b = whole.steady(), chunked.steady()
    assert np.array_equal(a.lo, b.lo) and np.array_equal(a.hi, b.hi) and np.allclose(a.common, b.common)
    assert 4.5 < a.common[-1] - a.common[0] < 6.0        # the ramp between the first and last block centres
    assert float(np.median(a.range)) < 2.5 < float(np.median(whole.range))   # resting cells: own wander only
