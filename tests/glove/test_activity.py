"""CellActivity's statistics (htdata/glove/activity.py) computed for every cell at once equal numpy's per-cell ones."""

from __future__ import annotations

import warnings

import numpy as np

from htdata.glove.activity import WANDER_BLOCK, WANDER_QUIET_K, CellActivity


def _cell_wander_per_cell(activity: CellActivity) -> np.ndarray:
    """cell_wander as written before it was vectorised: numpy's nanmedian / nanpercentile (a loop over cells), on
    the same block means (the glove's common mode taken out)."""
    b = activity.steady().blocks
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mid = np.nanmedian(b, axis=0)
        low = np.where(b <= mid, b, np.nan)
        spread = 1.4826 * np.nanmedian(np.abs(low - np.nanmedian(low, axis=0)), axis=0)
        quiet = np.where(b <= np.nanpercentile(b, 10, axis=0) + WANDER_QUIET_K * spread, b, np.nan)
        out = np.nanmax(quiet, axis=0) - np.nanmin(quiet, axis=0)
    return out.reshape(activity.grid)


def _nan_bearing_rows(seed: int, frames: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = 550 + rng.uniform(-30, 30, (1, 6, 7)) + rng.normal(0, 2.0, (frames, 6, 7))
    x += np.cumsum(rng.normal(0, 0.05, (frames, 6, 7)), axis=0)          # slow wander
    x[frames // 3: frames // 2, 1, 1] += 200                              # a held press
    x[rng.random(x.shape) < 0.05] = np.nan                                # scattered dropouts
    x[:, 0, 0] = np.nan                                                   # a cell never finite
    x[: 3 * WANDER_BLOCK, 2, 3] = np.nan                                  # whole blocks missing
    x[:, 4, 5] = np.inf                                                   # never finite either (Inf)
    x[:, 5, 6] = 600.0                                                    # constant
    return np.round(x * 2) / 2                                            # 0.5-count steps, like float16 counts


def test_cell_wander_equals_the_per_cell_numpy_result_on_nan_bearing_rows():
    for seed, frames in ((0, 40), (1, 333), (2, 2000)):
        act = CellActivity((6, 7))
        for chunk in np.array_split(_nan_bearing_rows(seed, frames), 5):   # streamed in uneven chunks
            act.add(chunk)
        ours, ref = act.cell_wander(), _cell_wander_per_cell(act)
        np.testing.assert_array_equal(np.isnan(ours), np.isnan(ref))
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9, equal_nan=True)
        assert np.isnan(ours[0, 0]) and np.isnan(ours[4, 5]) and np.isfinite(ours[5, 6])   # constant: the common mode's
        if frames > 4 * WANDER_BLOCK:
            assert np.isfinite(ours[1:4, 1:5]).all() and (ours[1:4, 1:5] > 0).all()


def test_cell_wander_needs_two_blocks():
    act = CellActivity((2, 2))
    act.add(np.zeros((2 * WANDER_BLOCK - 1, 2, 2), np.float32))
    assert np.isnan(act.cell_wander()).all() and act.wander() == 0.0
    act.add(np.ones((1, 2, 2), np.float32))
    assert np.isfinite(act.cell_wander()).all()


def test_huge_raw_values_leave_no_numpy_warning():
    """Issue 44 weak edge: a glove row of 3e38 leaked 'overflow encountered in multiply' onto the console."""
    import warnings

    from htdata.glove.activity import CellActivity

    rows = np.full((12, 4, 4), 500.0, np.float32)
    rows[5:8] = 3e38
    act = CellActivity((4, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        act.add(rows)
    assert act.frames == 12
