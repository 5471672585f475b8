"""Rasterisation mode x glove layout: render speed vs taxel round-trip error."""

from __future__ import annotations

import time

import numpy as np

from htdata.format.tactilesettings import TactileConfig
from htdata.glove.layouts import list_layouts, load_layout
from htdata.glove.rasterise import MODES, Rasteriser


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


CRITERION = ("exact taxel round trip (max round-trip error 0 on every layout: the map gives the taxel "
             "values back), then the least render time summed over the layouts")


def raster_default(rows: list[dict]) -> tuple[str | None, str]:
    """(the mode CRITERION picks from `rows`, why); None when no mode is exact on every layout."""
    modes = list(dict.fromkeys(r["mode"] for r in rows))
    worst = {m: max(r["max_roundtrip_error"] for r in rows if r["mode"] == m) for m in modes}
    ms = {m: sum(r["ms_per_frame"] for r in rows if r["mode"] == m) for m in modes}
    exact = sorted((m for m in modes if worst[m] == 0), key=lambda m: ms[m])
    others = ", ".join(f"{m} max error {worst[m]:.3g}" for m in modes if worst[m] != 0) or "none"
    if not exact:
        return None, f"no mode is exact on every layout ({others})"
    return exact[0], (f"{exact[0]}: max round-trip error 0 on every layout, {ms[exact[0]]:.2f} ms/frame summed "
                      f"over them; not exact: {others}")


def raster_rows(frames: int, layouts: list[str] | None = None) -> dict:
    """One row per (shipped layout, raster mode), the mode CRITERION picks, and the pipeline default."""

    rows = [raster_benchmark(layout_id, mode, frames=frames)
            for layout_id in layouts or list_layouts() for mode in MODES]
    chosen, why = raster_default(rows)
    code = TactileConfig().raster_mode
    return {"rows": rows, "default": chosen, "code_default": code, "criterion": CRITERION,
            "reason": f"{why}; the pipeline default ([tactile] raster_mode) is {code}: "
                      + ("the same" if code == chosen else "DIFFERENT")}
