"""Rasteriser: taxel grids <-> canonical maps (exactness, no bleeding, hard inputs)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
import scipy.sparse as sp

from htdata.benchmarks.raster import raster_benchmark
from htdata.format.canvas import CANVAS
from htdata.format.tactilecodec import to_half
from htdata.glove.layouts import GROUPS, load_canonical, load_layout
from htdata.glove.rasterise import BILINEAR_ROUNDTRIP_BOUND, MODES, Rasteriser

SHIPPED = ["opentouch_right_16x16", "touchanything_left_21x21", "touchanything_right_21x21"]
CASES = [(lid, m) for lid in SHIPPED for m in MODES]


@lru_cache(maxsize=None)
def _rast(lid: str, mode: str) -> Rasteriser:
    return Rasteriser(load_layout(lid), mode=mode)


def _random_grids(r: Rasteriser, T: int, seed: int = 0) -> np.ndarray:
    g = np.random.default_rng(seed).random((T, *r.layout.grid), dtype=np.float32)
    g[:, ~r.layout.live_mask] = np.nan
    return g


def _target_mask(place: str) -> np.ndarray:
    c = load_canonical()
    if place in c.places:
        return c.region_map == c.region_ids[place]
    return c.part_map == GROUPS.index(place) + 1


@pytest.mark.parametrize("lid, mode", CASES)
def test_roundtrip(lid, mode):
    r = _rast(lid, mode)
    g = _random_grids(r, 16)
    back = r.sample(r.render(g))
    live = r.layout.live_mask
    err = np.abs(back - g)[:, live]
    print(f"{lid} {mode}: max round-trip error {err.max():.3g}")
    assert np.isnan(back[:, ~live]).all()
    assert np.isfinite(back[:, live]).all()
    if mode == "nearest":
        assert err.max() < 1e-6
    else:
        assert err.max() < BILINEAR_ROUNDTRIP_BOUND


@pytest.mark.parametrize("lid, mode", CASES)
def test_no_bleeding_between_blocks(lid, mode):
    r = _rast(lid, mode)
    for b in r.layout.blocks:
        g = np.zeros((1, *r.layout.grid), np.float32)
        g[0, b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = 1.0
        lit = r.render(g)[0] > 0
        target = _target_mask(b.place)
        assert lit.any(), b.name
        assert not (lit & ~target).any(), f"block {b.name} bleeds outside {b.place}"
        assert np.array_equal(lit, target & (r.coverage == 1)), b.name


@pytest.mark.parametrize("lid, mode", CASES)
def test_zeros_and_constant(lid, mode):
    r = _rast(lid, mode)
    z = r.render(np.zeros((2, *r.layout.grid), np.float32))
    assert z.dtype == np.float32 and not z.any()
    ones = np.zeros((1, *r.layout.grid), np.float32)
    ones[:, r.layout.live_mask] = 1.0
    m = r.render(ones)[0]
    if mode == "nearest":
        assert np.array_equal(m, r.coverage.astype(np.float32))
    else:  # renormalised weights over live neighbours: no dimming next to dead cells
        assert np.abs(m - r.coverage).max() < 1e-6
        assert np.array_equal(m > 0, r.coverage == 1)


@pytest.mark.parametrize("lid, mode", CASES)
def test_uncovered_pixels_are_exactly_zero(lid, mode):
    r = _rast(lid, mode)
    m = r.render(_random_grids(r, 4, seed=3))
    assert not m[:, r.coverage == 0].any()
    assert ((m >= 0) & (m <= 1)).all()
    assert r.coverage.dtype == np.uint8 and set(np.unique(r.coverage).tolist()) <= {0, 1}
    assert not r.coverage[load_canonical().region_map == 0].any()


def test_coverage_fractions():
    fr = {lid: _rast(lid, "nearest").coverage_fraction for lid in SHIPPED}
    print("coverage fractions:", {k: round(v, 3) for k, v in fr.items()})
    assert fr["opentouch_right_16x16"] == 1.0  # every place has taxels, no dead cell inside a block
    assert 0.5 < fr["touchanything_left_21x21"] < 0.8  # fingertips + palm only
    assert fr["touchanything_left_21x21"] == fr["touchanything_right_21x21"]
    # the 4 dead palm cells (upper radial corner) leave a hole in the palm
    c = load_canonical()
    x0, y0, x1, y1 = c.places["palm.upper_radial"]
    assert _rast("touchanything_left_21x21", "nearest").coverage[y0 + 2, x1 - 3] == 0
    assert _rast("touchanything_left_21x21", "nearest").coverage[y0 + 2, x0 + 2] == 1


@pytest.mark.parametrize("mode", MODES)
def test_nonlive_garbage_is_ignored(mode):
    r = _rast("touchanything_left_21x21", mode)
    clean = _random_grids(r, 3, seed=1)
    clean[:, ~r.layout.live_mask] = 0
    dirty = clean.copy()
    junk = np.array([np.nan, np.inf, -np.inf, 1e30], np.float32)
    dirty[:, ~r.layout.live_mask] = np.resize(junk, (~r.layout.live_mask).sum())
    out = r.render(dirty)
    assert np.isfinite(out).all()
    assert np.array_equal(out, r.render(clean))


@pytest.mark.parametrize("mode", MODES)
def test_nonfinite_live_taxel_does_not_crash(mode):
    r = _rast("opentouch_right_16x16", mode)
    g = np.zeros((2, 16, 16), np.float32)
    g[0, 0, 0] = np.nan  # caller's problem (normalise drops such frames); render must survive
    g[1, 0, 0] = np.inf
    out = r.render(g)
    assert out.shape == (2, CANVAS, CANVAS)
    assert np.isnan(out[0]).any() and np.isfinite(out[0][load_canonical().part_map != 5]).all()
    assert out[1].max() == 1.0  # +inf clipped


@pytest.mark.parametrize("T", [0, 1, 1000])
def test_batch_shapes_and_dtype(T):
    r = _rast("opentouch_right_16x16", "nearest")
    g = np.random.default_rng(T).random((T, 16, 16)).astype(np.float32)
    maps = r.render(g)
    assert maps.shape == (T, CANVAS, CANVAS) and maps.dtype == np.float32
    back = r.sample(maps)
    assert back.shape == (T, 16, 16) and back.dtype == np.float32
    if T:
        assert np.array_equal(r.render(g[-1:])[0], maps[-1])  # batching does not change a frame


def test_input_dtypes_and_clipping():
    r = _rast("opentouch_right_16x16", "bilinear")
    g64 = np.random.default_rng(5).random((2, 16, 16))
    g16 = g64.astype(np.float16)
    assert r.render(g64).dtype == np.float32
    assert np.abs(r.render(g16) - r.render(g16.astype(np.float32))).max() == 0
    big = np.full((1, 16, 16), np.finfo(np.float16).max, np.float16)  # 65504
    assert r.render(big).max() == 1.0
    assert r.render(-np.ones((1, 16, 16), np.float32)).min() == 0.0


def test_bad_shapes_and_mode():
    r = _rast("opentouch_right_16x16", "nearest")
    with pytest.raises(ValueError, match=r"opentouch_right_16x16.*\(T,16,16\).*\(2, 21, 21\)"):
        r.render(np.zeros((2, 21, 21), np.float32))
    with pytest.raises(ValueError, match="expected"):
        r.render(np.zeros((16, 16), np.float32))
    with pytest.raises(ValueError, match="expected"):
        r.sample(np.zeros((1, 100, 100), np.float32))
    with pytest.raises(ValueError, match="mode must be one of"):
        Rasteriser(r.layout, mode="bicubic")


def test_matrix_is_sparse_and_reproduces_render():
    r = _rast("touchanything_left_21x21", "bilinear")
    assert sp.issparse(r.matrix) and r.matrix.format == "csr"
    assert r.matrix.shape == (21 * 21, CANVAS * CANVAS)
    assert r.matrix[np.flatnonzero(~r.layout.live_mask.reshape(-1))].nnz == 0  # non-live cells never read
    g = _random_grids(r, 2, seed=7)
    x = np.nan_to_num(g.reshape(2, -1), nan=0.0)
    ref = np.clip(np.asarray(x @ r.matrix), 0, 1).reshape(2, CANVAS, CANVAS)
    assert np.abs(ref - r.render(g)).max() < 1e-6


@pytest.mark.parametrize("lid", SHIPPED)
def test_thumb_contact_lands_on_thumb(lid):
    r = _rast(lid, "nearest")
    thumb_blocks = [b for b in r.layout.blocks if b.place.startswith("thumb")]
    assert thumb_blocks
    g = np.zeros((1, *r.layout.grid), np.float32)
    for b in thumb_blocks:
        g[0, b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = 1
    lit = r.render(g)[0] > 0
    parts = np.unique(load_canonical().part_map[lit])
    assert parts.tolist() == [1]


def test_orientation_of_single_taxels():
    """A taxel lands on the side of its place that anatomy says it should."""
    c = load_canonical()

    def lit_centre(lid, r_, c_):
        ras = _rast(lid, "nearest")
        g = np.zeros((1, *ras.layout.grid), np.float32)
        g[0, r_, c_] = 1
        ys, xs = np.nonzero(ras.render(g)[0])
        return xs.mean(), ys.mean()

    x0, y0, x1, y1 = c.places["little.distal"]
    x, y = lit_centre("opentouch_right_16x16", 0, 0)  # little tip, ulnar column, top row
    assert x0 <= x < (x0 + x1) / 2 and y0 <= y < (y0 + y1) / 2
    # TouchAnything left little tip col 1 (ulnar) == right grid col 19
    xl, _ = lit_centre("touchanything_left_21x21", 2, 1)
    xr, _ = lit_centre("touchanything_right_21x21", 2, 19)
    assert xl == xr and xl < (x0 + x1) / 2
    # palm: left col 19 is radial -> right side of the palm
    px0, _, px1, _ = c.groups["palm"]
    xp, _ = lit_centre("touchanything_left_21x21", 15, 19)
    assert xp > (px0 + px1) / 2


@pytest.mark.parametrize("mode", MODES)
def test_touchanything_left_right_mirror(mode):
    left, right = _rast("touchanything_left_21x21", mode), _rast("touchanything_right_21x21", mode)
    g = _random_grids(left, 4, seed=11)
    g[:, left.layout.bend_cells[:, 0], left.layout.bend_cells[:, 1]] = np.linspace(0, 1, 66, dtype=np.float32)
    g_right = np.ascontiguousarray(g[:, :, ::-1])  # stored mirrored
    mirror_rows = np.arange(21 * 21).reshape(21, 21)[:, ::-1].reshape(-1)
    assert abs(left.matrix - right.matrix[mirror_rows]).max() == 0  # identical weights
    # Same weights, summed in another cell order: equal up to float32 rounding.
    assert np.abs(left.render(g) - right.render(g_right)).max() <= (0 if mode == "nearest" else 1e-6)
    assert np.array_equal(left.coverage, right.coverage)
    assert np.array_equal(left.bend_vector(g), right.bend_vector(g_right))


def test_bend_vector():
    r = _rast("touchanything_left_21x21", "nearest")
    g = np.zeros((3, 21, 21), np.float32)
    bc = r.layout.bend_cells
    g[:, bc[:, 0], bc[:, 1]] = np.arange(66, dtype=np.float32)
    v = r.bend_vector(g)
    assert v.shape == (3, 66) and v.dtype == np.float32
    assert np.array_equal(v[1], np.arange(66, dtype=np.float32))
    assert not r.render(g).any()  # bend cells are never drawn
    ot = _rast("opentouch_right_16x16", "nearest")
    assert ot.bend_vector(np.zeros((5, 16, 16), np.float32)).shape == (5, 0)


def test_sample_ignores_outside_pixels_and_single_frame():
    r = _rast("opentouch_right_16x16", "bilinear")
    g = _random_grids(r, 1, seed=2)
    m = r.render(g)
    m[:, r.coverage == 0] = np.nan  # garbage outside the glove's coverage
    back = r.sample(m)
    assert np.isfinite(back[:, r.layout.live_mask]).all()


def test_raster_benchmark_reports():
    res = raster_benchmark("opentouch_right_16x16", "nearest", frames=8)
    assert set(res) >= {"ms_per_frame", "max_roundtrip_error", "rmse"}
    assert res["max_roundtrip_error"] < 1e-6 and res["ms_per_frame"] > 0


@pytest.mark.parametrize("lid", SHIPPED)
def test_nearest_gather_is_the_sparse_product_byte_for_byte(lid):
    """Nearest mode renders by gather; it must give the CSR product's exact bytes, hard values included."""
    r = _rast(lid, "nearest")
    assert r._gather is not None
    g = np.random.default_rng(3).normal(0.5, 0.8, (6, *r.layout.grid)).astype(np.float32)   # beyond [0,1] too
    g[0, 0, :] = np.nan
    g[1] = -0.0
    g[2, 1, 1] = np.inf
    x = g.reshape(6, -1)[:, r.live_index]
    product = np.ascontiguousarray((r._render_t @ x.T).T, dtype=np.float32)
    np.clip(product, 0.0, 1.0, out=product)
    rendered = r.render(g)
    assert rendered.dtype == np.float32 and rendered.flags["C_CONTIGUOUS"]
    assert rendered.reshape(6, -1).tobytes() == product.tobytes()
    assert r.render(g[:1]).tobytes() == rendered[:1].tobytes()          # one frame at a time: the same


@pytest.mark.parametrize("lid", SHIPPED)
def test_bilinear_keeps_the_sparse_product(lid):
    assert _rast(lid, "bilinear")._gather is None


@pytest.mark.parametrize("lid, mode", CASES)
def test_frames_render_each_map_as_render_does_byte_for_byte(lid, mode):
    """`frames(g)[n]` (the ingest's one-map-at-a-time path) equals `render(g)[n]`: hard values, non-live junk."""
    r = _rast(lid, mode)
    g = np.random.default_rng(4).normal(0.5, 0.8, (5, *r.layout.grid)).astype(np.float32)   # beyond [0,1] too
    g[0, 0, :] = np.nan
    g[1] = -0.0
    g[2, 1, 1] = np.inf
    g[3] = 0.0
    g[4, ~r.layout.live_mask] = 1e30
    frames, rendered = r.frames(g), r.render(g)
    assert len(frames) == 5
    for n in range(5):
        got = frames[n]
        assert got.shape == (CANVAS, CANVAS) and got.dtype == np.float32
        assert got.tobytes() == rendered[n].tobytes()
    with pytest.raises(IndexError):
        frames[5]
    half = r.frames(g, np.float16)       # the stored pixels of a "half" dataset: to_half of the same map
    for n in range(5):
        assert half[n].dtype == np.float16 and half[n].tobytes() == to_half(rendered[n]).tobytes()
    assert len(r.frames(np.zeros((0, *r.layout.grid), np.float32))) == 0
    with pytest.raises(ValueError, match="expected"):
        r.frames(np.zeros(r.layout.grid, np.float32))
    with pytest.raises(ValueError, match="float32 or float16"):
        r.frames(g, np.float64)
