"""Rasterisation mode x glove layout: render speed vs taxel round-trip error."""

from __future__ import annotations

from htdata.layouts import list_layouts
from htdata.rasterise import MODES, raster_benchmark


def raster_rows(frames: int, layouts: list[str] | None = None) -> list[dict]:
    rows = []
    for layout_id in layouts or list_layouts():
        for mode in MODES:
            rows.append(raster_benchmark(layout_id, mode, frames=frames))
    return rows
