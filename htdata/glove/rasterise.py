"""Taxel grids (T,H,W) -> canonical 224x224 tactile maps, and back.

Per layout and mode one sparse matrix M (H*W, 224*224) is built once, so a
batch renders as a single sparse product. Each block is resampled over its
place (or group) rectangle with the pixel-centre convention
(align_corners=False): pixel j of a rectangle of P pixels covering n cells
sits at cell coordinate (j + 0.5) * n / P - 0.5. A pixel only ever reads
cells of its own block, so regions never bleed into each other.

NaN/Inf: cells that are not live are never read (NaN there is harmless).
Non-finite LIVE taxels propagate into the map (render does not crash); the
caller (normalise) checks finiteness first and drops such frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from htdata.errors import ArgumentError, ConfigError
from htdata.format.canvas import CANVAS
from htdata.format.tactilecodec import to_half
from htdata.glove.layouts import Block, CanonicalHand, Layout, load_canonical, load_layout

MODES = ("nearest", "bilinear")
NPIX = CANVAS * CANVAS
# Max |sample(render(g)) - g| over live taxels for uniform random g in
# bilinear mode: measured 0.068 (opentouch) and 0.107 (touchanything, palm
# rows whose centres fall in the gaps between palm places) with
# htdata.benchmarks.raster.raster_benchmark(..., frames=256); tests assert this bound. Nearest mode
# round-trips exactly (float64 footprint means).
BILINEAR_ROUNDTRIP_BOUND = 0.15


@dataclass(frozen=True)
class _Triplets:
    """Sparse entries (row, col, weight) collected block by block."""

    rows: np.ndarray
    cols: np.ndarray
    vals: np.ndarray


def _concat(parts: list[_Triplets]) -> _Triplets:
    if not parts:
        e = np.zeros(0, np.int64)
        return _Triplets(e, e, np.zeros(0, np.float64))
    return _Triplets(np.concatenate([p.rows for p in parts]), np.concatenate([p.cols for p in parts]),
                     np.concatenate([p.vals for p in parts]))


def _axis_neighbours(pix_local: np.ndarray, n_pix: int, n_cells: int):
    """Nearest cell and the two clamped bilinear cells (+ weights) along one axis."""
    u = (pix_local + 0.5) * (n_cells / n_pix) - 0.5
    nearest = np.clip(np.floor(u + 0.5), 0, n_cells - 1).astype(np.int64)
    lo = np.floor(u)
    frac = u - lo
    lo = lo.astype(np.int64)
    a = np.clip(lo, 0, n_cells - 1)
    b = np.clip(lo + 1, 0, n_cells - 1)
    return nearest, (a, 1.0 - frac), (b, frac)


@dataclass(frozen=True)
class _BlockGeometry:
    pix: np.ndarray  # flat canvas index of every pixel the block may draw on
    nearest_cell: np.ndarray  # flat grid index of each pixel's nearest cell
    covered: np.ndarray  # bool per pixel: its nearest cell is live


def _block_geometry(block: Block, canon: CanonicalHand, layout: Layout) -> tuple[_BlockGeometry, tuple]:
    x0, y0, x1, y1 = canon.target_rect(block.place)
    ys, xs = np.nonzero(canon.target_mask(block.place))
    h, w = block.display_shape
    ny, ay, by = _axis_neighbours(ys - y0, y1 - y0, h)
    nx, ax, bx = _axis_neighbours(xs - x0, x1 - x0, w)
    nearest = _flat_cell(block, ny, nx, layout)
    covered = layout.live_mask.reshape(-1)[nearest]
    geom = _BlockGeometry(pix=ys * CANVAS + xs, nearest_cell=nearest, covered=covered)
    return geom, (ay, by, ax, bx)


def _render_triplets(block: Block, canon: CanonicalHand, layout: Layout, mode: str):
    geom, (ay, by, ax, bx) = _block_geometry(block, canon, layout)
    keep = geom.covered
    pix = geom.pix[keep]
    if mode == "nearest":
        t = _Triplets(geom.nearest_cell[keep], pix, np.ones(len(pix)))
        return t, geom
    live = layout.live_mask.reshape(-1)
    cells, weights = [], []
    for (ry, wy) in (ay, by):
        for (rx, wx) in (ax, bx):
            c = _flat_cell(block, ry[keep], rx[keep], layout)
            cells.append(c)
            weights.append(wy[keep] * wx[keep] * live[c])  # dead neighbours get no weight
    cells_a = np.stack(cells)  # (4, n)
    w_a = np.stack(weights)
    w_a = w_a / w_a.sum(axis=0, keepdims=True)  # > 0: the nearest (live) cell is a neighbour
    nz = w_a > 0
    t = _Triplets(cells_a[nz], np.broadcast_to(pix, cells_a.shape)[nz], w_a[nz])
    return t, geom


def _sample_triplets(block: Block, canon: CanonicalHand, layout: Layout, geom: _BlockGeometry,
                     mode: str, covered_canvas: np.ndarray) -> _Triplets:
    """Rows = live cells, cols = pixels: how each taxel is read back from a map."""
    live = layout.live_mask.reshape(-1)
    own = geom.nearest_cell[geom.covered]
    pix = geom.pix[geom.covered]
    # Footprint mean: every covered pixel votes for its nearest cell.
    uniq, inverse, counts = np.unique(own, return_inverse=True, return_counts=True)
    block_cells = _block_cells(block, layout.grid)
    block_live = block_cells[live[block_cells]]
    missing = np.setdiff1d(block_live, uniq)
    if len(missing):
        r, c = divmod(int(missing[0]), layout.grid[1])
        raise ConfigError(f"layout {layout.layout_id}: block {block.name!r}: live cell [{r}, {c}] has no pixel "
                          f"in place {block.place!r} (place too small or masked by gaps)")
    footprint = _Triplets(own, pix, 1.0 / counts[inverse])
    if mode == "nearest":
        return footprint
    # Bilinear value at each taxel centre, over covered pixels of this block only.
    x0, y0, x1, y1 = canon.target_rect(block.place)
    h, w = block.display_shape
    r_raw, c_raw = np.divmod(block_live, layout.grid[1])
    dr, dc = block.display_cell(r_raw, c_raw)
    in_block = np.zeros(NPIX, bool)
    in_block[pix] = True
    in_block &= covered_canvas
    # Same centre convention read the other way: cell i of n sits at pixel (i + 0.5) * P / n - 0.5.
    _, py_a, py_b = _axis_neighbours(dr.astype(np.float64), h, y1 - y0)
    _, px_a, px_b = _axis_neighbours(dc.astype(np.float64), w, x1 - x0)
    rows, cols, vals = [], [], []
    for (oy, wy) in (py_a, py_b):
        for (ox, wx) in (px_a, px_b):
            p = (y0 + oy) * CANVAS + (x0 + ox)
            rows.append(block_live)
            cols.append(p)
            vals.append(wy * wx * in_block[p])
    rows_a, cols_a, vals_a = np.stack(rows), np.stack(cols), np.stack(vals)
    total = vals_a.sum(axis=0)
    ok = total > 0
    vals_a[:, ok] /= total[ok]
    nz = (vals_a > 0) & ok[None, :]
    # A centre whose 2x2 pixels are all uncovered (it falls in a gap between
    # places of a group) reads the pixels of its footprint closest to it.
    cy = y0 + (dr + 0.5) * (y1 - y0) / h - 0.5
    cx = x0 + (dc + 0.5) * (x1 - x0) / w - 0.5
    fallback = _closest_footprint_pixels(footprint, block_live[~ok], cy[~ok], cx[~ok])
    return _concat([_Triplets(rows_a[nz], cols_a[nz], vals_a[nz]), fallback])


def _closest_footprint_pixels(footprint: _Triplets, cells: np.ndarray, cy: np.ndarray, cx: np.ndarray) -> _Triplets:
    """For each cell, equal weights over its footprint pixels nearest to (cy, cx)."""
    sel = np.isin(footprint.rows, cells)
    rows, pix = footprint.rows[sel], footprint.cols[sel]
    order = np.searchsorted(cells, rows, sorter=np.argsort(cells))
    slot = np.argsort(cells)[order]  # index into cells/cy/cx of each entry
    py, px = np.divmod(pix, CANVAS)
    d2 = (py - cy[slot]) ** 2 + (px - cx[slot]) ** 2
    best = np.full(len(cells), np.inf)
    np.minimum.at(best, slot, d2)
    keep = d2 <= best[slot] + 1e-9
    n = np.bincount(slot[keep], minlength=len(cells))
    return _Triplets(rows[keep], pix[keep], 1.0 / n[slot[keep]])


def _flat_cell(block: Block, display_rows: np.ndarray, display_cols: np.ndarray, layout: Layout) -> np.ndarray:
    """Flat grid index of the raw cell drawn at each (row, col) of the block's display array."""
    r, c = block.raw_cell(display_rows, display_cols)
    return r * layout.grid[1] + c


def _block_cells(block: Block, grid: tuple[int, int]) -> np.ndarray:
    r = np.arange(block.rows[0], block.rows[1] + 1)
    c = np.arange(block.cols[0], block.cols[1] + 1)
    return (r[:, None] * grid[1] + c[None, :]).reshape(-1)


def _gather_index(render_t: sp.csr_matrix) -> np.ndarray | None:
    """(P,) live-taxel index of each pixel (L = none) when every pixel reads at most one taxel at weight 1.

    That is nearest mode: rendering is then `take` on the taxels plus a zero column, exactly the
    sparse product's values (1 * x is x; an empty row gives 0), without its (P, T) transpose copy.
    """
    per_pixel = np.diff(render_t.indptr)
    if per_pixel.size == 0 or per_pixel.max() > 1 or not np.all(render_t.data == 1.0):
        return None
    index = np.full(render_t.shape[0], render_t.shape[1], np.intp)
    covered = np.flatnonzero(per_pixel)
    index[covered] = render_t.indices[render_t.indptr[covered]]
    return index


class Rasteriser:
    """Render taxel grids of one glove layout onto the canonical hand, and sample back."""

    def __init__(self, layout: Layout | str, mode: str = "nearest", canonical: CanonicalHand | None = None):
        if mode not in MODES:
            raise ArgumentError(f"Rasteriser: mode must be one of {MODES}, got {mode!r}")
        self.layout = layout if isinstance(layout, Layout) else load_layout(layout)
        self.mode = mode
        self.canonical = canonical or load_canonical()
        H, W = self.layout.grid
        ncell = H * W
        parts, geoms = [], []
        coverage = np.zeros(NPIX, np.uint8)
        for b in self.layout.blocks:
            t, g = _render_triplets(b, self.canonical, self.layout, mode)
            parts.append(t)
            geoms.append(g)
            coverage[g.pix[g.covered]] = 1
        t = _concat(parts)
        #: (H*W, 224*224) CSR: maps_flat = grids_flat @ matrix (rows of non-live cells are empty).
        self.matrix = sp.csr_matrix((t.vals.astype(np.float32), (t.rows, t.cols)), shape=(ncell, NPIX))
        self.live_index = np.flatnonzero(self.layout.live_mask.reshape(-1))
        # Transposed, live rows only: a (P, L) CSR times (L, T) dense is scipy's fast path.
        self._render_t = self.matrix[self.live_index].T.tocsr()
        self._gather = _gather_index(self._render_t)
        s = _concat([_sample_triplets(b, self.canonical, self.layout, g, mode, coverage.astype(bool))
                     for b, g in zip(self.layout.blocks, geoms)])
        # float64 so a footprint mean of equal values reproduces the value exactly.
        sample = sp.csr_matrix((s.vals, (s.rows, s.cols)), shape=(ncell, NPIX))
        live = sample[self.live_index].tocsr()  # (L, P)
        # Only the pixels some taxel reads: gathering them first shrinks the float64 copy scipy
        # needs ~5x (same rows, same entry order: bit-identical results).
        self._sample_pixels = np.unique(live.indices)
        self._sample_live = live[:, self._sample_pixels].tocsr()  # (L, pixels read)
        self.coverage = coverage.reshape(CANVAS, CANVAS)
        self.coverage.setflags(write=False)
        bend = self.layout.bend_cells
        self._bend_r, self._bend_c = bend[:, 0], bend[:, 1]

    @property
    def coverage_fraction(self) -> float:
        """Fraction of the canonical hand's pixels (inside places) under a live taxel."""
        hand = self.canonical.region_map > 0
        return float(self.coverage[hand].sum() / hand.sum())

    def _check(self, arr: np.ndarray, shape: tuple[int, ...], what: str) -> np.ndarray:
        a = np.asarray(arr)
        if a.ndim != 3 or a.shape[1:] != shape:
            raise ValueError(f"{what} for layout {self.layout.layout_id}: expected (T,{shape[0]},{shape[1]}), "
                             f"got {a.shape}")
        return a

    def render(self, grids: np.ndarray) -> np.ndarray:
        """(T,H,W) normalised taxels -> (T,224,224) float32 in [0,1]; non-live cells ignored."""
        g = self._check(grids, self.layout.grid, "render: grids")
        T = g.shape[0]
        if T == 0:
            return np.zeros((0, CANVAS, CANVAS), np.float32)
        x = g.reshape(T, -1)[:, self.live_index].astype(np.float32)  # non-live cells never read
        if self._gather is not None:
            # Nearest mode: one taxel per pixel, weight 1, so the product is a gather. Clipping the
            # taxels first gives the same map (uncovered pixels are 0 either way) at a fraction of the
            # work; "+ 0.0" turns -0.0 into +0.0 as the product's 0 + 1 * x did (same EXR bytes).
            x = np.concatenate([np.clip(x, 0.0, 1.0) + 0.0, np.zeros((T, 1), np.float32)], axis=1)
            return np.take(x, self._gather, axis=1).reshape(T, CANVAS, CANVAS)
        out = np.ascontiguousarray((self._render_t @ x.T).T, dtype=np.float32)
        np.clip(out, 0.0, 1.0, out=out)
        return out.reshape(T, CANVAS, CANVAS)

    def frames(self, grids: np.ndarray, dtype=np.float32) -> "RenderedFrames":
        """The maps of (T,H,W) grids, each rendered when asked: `frames(g)[n]` equals `render(g)[n]` bit for bit
        (float32), or its float16 rounding, bit for bit (`dtype=np.float16`: `to_half(render(g)[n])`).

        For a caller that takes one frame's map at a time (the ingest: a chunk of rendered maps is
        200 KiB per frame and hand, its taxels 1/100th): in nearest mode the chunk's taxels are
        gathered, clipped (and rounded to half) once, so a map costs one `take` (~4x less than
        `render` of one frame; a half map, the dataset's stored pixels, skips the map's conversion).
        """
        g = self._check(grids, self.layout.grid, "frames: grids")
        if np.dtype(dtype) not in (np.dtype(np.float32), np.dtype(np.float16)):
            raise ArgumentError(f"Rasteriser.frames: dtype must be float32 or float16, got {np.dtype(dtype)}")
        half = np.dtype(dtype) == np.float16
        if self._gather is None:
            return RenderedFrames((lambda n: to_half(self.render(g[n:n + 1])[0])) if half
                                  else (lambda n: self.render(g[n:n + 1])[0]), len(g))
        T, (H, W) = g.shape[0], self.layout.grid
        taxels = g.reshape(T, H * W)[:, self.live_index].astype(np.float32)
        x = np.zeros((T, self.live_index.size + 1), np.float32)   # the last column: uncovered pixels read 0
        x[:, :-1] = np.clip(taxels, 0.0, 1.0) + 0.0                  # as render: clipped, -0.0 made +0.0
        if half:                                                     # elementwise, so the same as the map's
            x = to_half(x)
        gather = self._gather
        return RenderedFrames(lambda n: x[n].take(gather).reshape(CANVAS, CANVAS), T)

    def sample(self, maps: np.ndarray) -> np.ndarray:
        """(T,224,224) maps -> (T,H,W) taxel values (footprint mean or bilinear at centre); non-live NaN."""
        m = self._check(maps, (CANVAS, CANVAS), "sample: maps")
        T = m.shape[0]
        H, W = self.layout.grid
        out = np.full((T, H * W), np.nan, np.float32)
        if T:
            flat = m.reshape(T, -1)[:, self._sample_pixels].astype(np.float64)
            out[:, self.live_index] = (self._sample_live @ flat.T).T
        return out.reshape(T, H, W)

    def bend_vector(self, grids: np.ndarray) -> np.ndarray:
        """(T,H,W) -> (T,K) float32 values of the bend cells, in the layout's order."""
        g = self._check(grids, self.layout.grid, "bend_vector: grids")
        return g[:, self._bend_r, self._bend_c].astype(np.float32)


class RenderedFrames:
    """`Rasteriser.frames`: len() frames, `[n]` renders frame n's (224,224) map (float32 or float16)."""

    def __init__(self, render_one, count: int):
        self._render_one, self._count = render_one, count

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, n: int) -> np.ndarray:
        if not 0 <= n < self._count:
            raise IndexError(f"frame {n} of {self._count}")
        return self._render_one(n)
