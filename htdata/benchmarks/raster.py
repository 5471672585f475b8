"""Rasterisation mode x glove layout: render speed vs taxel round-trip error."""

from __future__ import annotations

import time

import numpy as np

from htdata.layouts import list_layouts, load_layout
from htdata.rasterise import MODES, Rasteriser


def raster_benchmark(layout_id: str, mode: str, frames: int = 256, seed: int = 0) -> dict:
    """Render speed and round-trip error on uniform random taxels (live cells only)."""
    r = Rasteriser(load_layout(layout_id), mode=mode)
    rng = np.random.default_rng(seed)
    H, W = r.layout.grid
    grids = rng.random((frames, H, W), dtype=np.float32)
    grids[:, ~r.layout.live_mask] = np.nan  # dead cells must be ignored
    r.render(grids[:2])  # warm-up
    t0 = time.perf_counter()
    maps = r.render(grids)
    elapsed = time.perf_counter() - t0
    back = r.sample(maps)
    err = (back - grids)[:, r.layout.live_mask]
    return {"layout_id": layout_id, "mode": mode, "frames": frames,
            "ms_per_frame": 1e3 * elapsed / max(frames, 1),
            "max_roundtrip_error": float(np.abs(err).max()) if err.size else 0.0,
            "rmse": float(np.sqrt(np.mean(err.astype(np.float64) ** 2))) if err.size else 0.0,
            "coverage": r.coverage_fraction}


def raster_rows(frames: int, layouts: list[str] | None = None) -> list[dict]:
    """One row per (shipped layout, raster mode)."""
    return [raster_benchmark(layout_id, mode, frames=frames)
            for layout_id in layouts or list_layouts() for mode in MODES]
