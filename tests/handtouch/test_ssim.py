import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from handtouch.bench.ssim import box_mean_valid, map_stats, ssim, ssim_query_candidates


def _sparse_maps(rng, n, size=224):
    """Contact-like maps: mostly zeros with a few smooth blobs."""
    maps = np.zeros((n, size, size), np.float32)
    yy, xx = np.mgrid[:size, :size]
    for i in range(n):
        for _ in range(3):
            cy, cx = rng.uniform(0, size, 2)
            r = rng.uniform(5, 30)
            maps[i] += np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r)).astype(np.float32)
    maps *= rng.uniform(0, 1, (n, size, size)) > 0.3
    return np.clip(maps, 0, 1)


def _ref(a, b):
    return structural_similarity(a.astype(np.float64), b.astype(np.float64), data_range=1.0)


def test_box_mean_matches_direct_window_means():
    x = torch.rand(2, 12, 10, dtype=torch.float64)
    got = box_mean_valid(x, 3)
    want = torch.nn.functional.avg_pool2d(x[:, None], 3, stride=1)[:, 0]
    assert got.shape == (2, 10, 8)
    assert torch.allclose(got, want, atol=1e-12)


def test_matches_skimage_on_random_and_sparse_maps():
    rng = np.random.default_rng(0)
    a = np.concatenate([rng.random((3, 224, 224), dtype=np.float32), _sparse_maps(rng, 3)])
    b = np.concatenate([rng.random((3, 224, 224), dtype=np.float32), _sparse_maps(rng, 3)])
    b[0] = np.clip(a[0] + rng.normal(0, 0.05, a[0].shape), 0, 1)  # highly similar pair
    got = ssim(a, b, data_range=1.0).numpy()
    want = np.array([_ref(x, y) for x, y in zip(a, b)])
    assert np.abs(got - want).max() < 1e-4
    # float32 skimage (its native precision for float32 input) agrees as well
    want32 = np.array([structural_similarity(x, y, data_range=1.0) for x, y in zip(a, b)])
    assert np.abs(got - want32).max() < 1e-4


def test_non_square_and_1x1xHxW_inputs():
    rng = np.random.default_rng(1)
    a, b = rng.random((2, 1, 30, 17))
    got = ssim(torch.tensor(a)[None], torch.tensor(b)[None], data_range=1.0)
    assert got.shape == (1,)
    assert abs(got.item() - _ref(a[0], b[0])) < 1e-6


def test_hard_cases_no_nan():
    z = np.zeros((224, 224), np.float32)
    half = np.full((224, 224), 0.5, np.float32)
    single = z.copy()
    single[100, 100] = 1.0
    got = ssim(np.stack([z, half, single]), np.stack([z, z, z]), data_range=1.0).numpy()
    assert not np.isnan(got).any()
    assert got[0] == pytest.approx(1.0)
    assert got[1] == pytest.approx(1e-4 / (0.25 + 1e-4), rel=1e-6)  # ~0.0004, C1 / (mu^2 + C1)
    assert got[2] == pytest.approx(_ref(single, z), abs=1e-6)
    assert got[2] > 0.99  # the empty background dominates


def test_float16_extremes_and_identical_maps():
    rng = np.random.default_rng(2)
    a = rng.random((224, 224)).astype(np.float16).astype(np.float32)
    a[0, :5] = [0.0, 6e-8, 1.0, 0.99951, 1e-4]  # float16 subnormal and top values
    assert ssim(a, a, data_range=1.0).item() == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("bad", [None, 0, 0.0, -1.0])
def test_data_range_is_required(bad):
    a = np.zeros((16, 16), np.float32)
    with pytest.raises(ValueError, match="data_range"):
        ssim(a, a, data_range=bad)
    with pytest.raises(ValueError, match="data_range"):
        ssim_query_candidates(map_stats(a), torch.tensor([0]), torch.tensor([[0]]), data_range=bad)


def test_rejects_nan_and_tiny_maps():
    a = np.zeros((16, 16), np.float32)
    b = a.copy()
    b[3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ssim(a, b, data_range=1.0)
    with pytest.raises(ValueError, match="smaller"):
        ssim(np.zeros((5, 16)), np.zeros((5, 16)), data_range=1.0)


def test_query_candidates_uses_cache_and_matches_pairwise():
    rng = np.random.default_rng(3)
    maps = np.concatenate([_sparse_maps(rng, 5, 64), rng.random((3, 64, 64), dtype=np.float32)])
    stats = map_stats(maps)
    queries = torch.tensor([0, 6])
    cands = torch.tensor([[1, 2, 3, 7], [0, 5, 6, 1]])
    got = ssim_query_candidates(stats, queries, cands, data_range=1.0).numpy()
    for r, q in enumerate(queries.tolist()):
        for c, j in enumerate(cands[r].tolist()):
            assert abs(got[r, c] - _ref(maps[q], maps[j])) < 1e-5
    assert got[1, 2] == pytest.approx(1.0)  # a map against itself


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_constant_map_against_itself_is_one(dtype):
    """float32 window statistics gave 1.0000379 here (mean 0.7 rounded to float32)."""
    m = np.full((224, 224), 0.7, dtype)
    assert abs(ssim(m, m, data_range=1.0).item() - 1.0) < 1e-7
    got = ssim_query_candidates(map_stats(m), torch.tensor([0]), torch.tensor([[0]]), data_range=1.0)
    assert abs(got.item() - 1.0) < 1e-7


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_near_ties_rank_like_skimage(dtype):
    """Query constant 0.7; candidates 0.70000003 and 0.7001 (float32 statistics ranked them the wrong way)."""
    q, near, far = (np.full((224, 224), v, dtype) for v in (0.7, 0.70000003, 0.7001))
    stats = map_stats(np.stack([q, near, far]))
    got = ssim_query_candidates(stats, torch.tensor([0, 0]), torch.tensor([[1, 2], [2, 1]]), data_range=1.0).numpy()
    want = np.array([_ref(q, near), _ref(q, far)])
    assert want[0] > want[1]
    assert got[0, 0] > got[0, 1] and got[1, 1] > got[1, 0]                # same order, either candidate order
    assert np.abs(got[0] - want).max() < 1e-12 and np.abs(got[1][::-1] - want).max() < 1e-12
    assert got[0, 0] - got[0, 1] > 1e-9                                   # well outside the retrieval tie tolerance


def test_zero_over_zero_cases_are_defined():
    """Constant / empty maps have zero variance: the structure term is C2 / C2 = 1, never 0/0."""
    z = np.zeros((2, 32, 32))
    assert ssim(z, z, data_range=1.0).tolist() == [1.0, 1.0]                # two empty maps: exactly 1
    c1 = 0.01 ** 2                    # K1 = 0.01, data_range 1; the structure term cancels for constant maps
    for a, b in ((0.3, 0.0), (1.0, 0.25), (0.5, 0.5)):
        got = ssim(np.full((32, 32), a), np.full((32, 32), b), data_range=1.0).item()
        assert got == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), abs=1e-12)
        assert got == pytest.approx(_ref(np.full((32, 32), a), np.full((32, 32), b)), abs=1e-12)
    # data_range 2 scales C1/C2: still defined
    assert ssim(z[0], z[0], data_range=2.0).item() == 1.0


def test_empty_batches_give_empty_results():
    none = np.zeros((0, 16, 16))
    assert ssim(none, none, data_range=1.0).shape == (0,)
    stats = map_stats(np.zeros((3, 16, 16)))
    out = ssim_query_candidates(stats, torch.zeros(0, dtype=torch.long), torch.zeros((0, 4), dtype=torch.long),
                                data_range=1.0)
    assert out.shape == (0, 4) and out.dtype == torch.float64
