"""The glove-only cost breakdown (htdata/benchmarks/mapcost.py): its deflate is the writer's, its projections
are the module docstring's formulas. No timing is asserted: only what the numbers are made of."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from isal import isal_zlib

from htdata.benchmarks.mapcost import _filtered_chunks, encode_costs, projections
from htdata.format.codec import encode_tactile
from htdata.format.exrzip import DEFLATE_LEVEL, LINES_PER_CHUNK


def _sparse_map(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    m = np.zeros((224, 224), np.float32)
    m[20:200, 10:210] = rng.random((180, 200)) * (rng.random((180, 200)) < 0.1)
    # rows 0-19 and 200-223 are zero: the first and the last chunk are all-zero, stored without a deflate
    return m.astype(np.float16)


def test_deflated_chunks_are_the_ones_the_writer_stores():
    m = _sparse_map(1)
    data = encode_tactile(m, "zip", pixel_type="half")
    chunks = _filtered_chunks(m)
    assert len(chunks) == 224 // LINES_PER_CHUNK - 2
    header_end = data.index(b"scanlineimage\0") + len("scanlineimage\0")   # the last attribute, then 0
    offsets = struct.unpack_from(f"<{224 // LINES_PER_CHUNK}Q", data, header_end)
    stored = [data[o + 8:o + 8 + struct.unpack_from("<i", data, o + 4)[0]] for o in offsets[1:-1]]
    assert stored == [isal_zlib.compress(c, DEFLATE_LEVEL) for c in chunks]


def test_encode_costs_counts_maps_chunks_and_bytes():
    maps = [_sparse_map(s) for s in range(3)]
    costs = encode_costs(maps, "half", reps=1)
    assert costs["maps"] == 3 and costs["nonzero_chunks_per_map"] == 12 and costs["deflate_level"] == DEFLATE_LEVEL
    chunks = [c for m in maps for c in _filtered_chunks(m)]
    assert costs["deflate_bytes"] == pytest.approx(sum(len(isal_zlib.compress(c, DEFLATE_LEVEL)) for c in chunks) / 3)
    assert costs["level0_bytes"] == pytest.approx(sum(len(isal_zlib.compress(c, 0)) for c in chunks) / 3)
    assert costs["encode_us"] >= 0 and costs["deflate_us"] >= 0 and costs["level0_us"] >= 0


def test_projections_follow_the_formulas():
    row = {"frames": 1000, "frames_per_s_raw": 1000.0, "frames_per_s_stored": 500.0,
           "encode_s_stored": 0.6, "rasterise_s_stored": 0.1}
    costs = {"maps": 2000, "deflate_us": 150.0, "level0_us": 50.0, "deflate_bytes": 2000.0, "level0_bytes": 3500.0}
    p = projections(row, costs)
    raw, stored = 1e-3, 2e-3
    assert p["maps_per_frame"] == 2 and p["raw_ms_per_frame"] == pytest.approx(1.0)
    assert p["budget_ms_per_frame"] == pytest.approx(0.25)
    assert p["ceiling_one_core"] == pytest.approx(raw / (raw + 2 * 150e-6 + 1e-4))
    assert p["level0_one_core"] == pytest.approx(raw / (stored - 2 * 100e-6))
    assert p["spare_core"] == pytest.approx(raw / (stored - 6e-4))
    assert p["level0_bytes_ratio"] == pytest.approx(1.75)
