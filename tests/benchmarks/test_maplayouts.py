"""The stored-map layout table of the codec bench (htdata/benchmarks/maplayouts.py): every variant reads
back exactly (its writer verified by read-back), and the pick follows its stated rule."""

from __future__ import annotations

import numpy as np
import pytest

from htdata.benchmarks.maplayouts import BYTES_BUDGET, TIE, layout_rows, pick_layout, variants
from htdata.format.tactilecodec import decode_exr

pytest.importorskip("OpenImageIO")


def _maps() -> np.ndarray:
    rng = np.random.default_rng(1)
    maps = np.zeros((3, 224, 224), np.float32)
    maps[0, 40:120, 60:100] = np.repeat(rng.random((8, 4), dtype=np.float32), 10, 0).repeat(10, 1)
    maps[1, 200:224, 0:30] = 1.0
    return maps            # maps[2]: no contact at all


def test_every_variant_reads_back_the_map_in_its_pixel_type():
    maps = _maps()
    for name, v in variants().items():
        for m in maps:
            got = decode_exr(v["encode"](m), name)
            want = m.astype(np.float16).astype(np.float32) if v["pixel"] == "half" else m
            np.testing.assert_array_equal(got, want, err_msg=name)


def test_the_table_measures_every_variant_with_its_error():
    rows = layout_rows(_maps(), reps=1)
    assert {r["layout"] for r in rows} == set(variants())
    assert all(r["max_error"] == 0.0 for r in rows if r["pixel"] == "float")
    assert all(0 < r["max_error"] <= 2.0 ** -12 for r in rows if r["pixel"] == "half")
    size = {r["layout"]: r["bytes_per_map"] for r in rows}
    assert size["exr_float_zip_window"] < size["exr_float_zip_binding"]    # a window saves bytes (same writer)
    writers = {r["layout"]: r["writer"] for r in rows}
    assert writers["exr_half_zip"].startswith("htdata") and writers["exr_half_zip_binding"] == "OpenEXR"


def _row(name, pixel, ms, size, err):
    return {"layout": name, "pixel": pixel, "encode_ms": ms, "bytes_per_map": size, "max_error": err}


def test_the_pick_is_exact_then_within_the_byte_budget_then_fastest_then_smallest():
    rows = [_row("half_fast", "half", 0.5, 3000, 2.0 ** -12),          # not exact for a 1/3072 glove
            _row("float_rle", "float", 0.8, 90_000, 0.0),              # fastest exact, far over the budget
            _row("float_zip", "float", 1.00, 5200, 0.0),
            _row("float_zip_window", "float", 1.00 * (1 + TIE / 2), 5000, 0.0),   # a tie, smaller: picked
            _row("float_zip_slow", "float", 1.5, 4500, 0.0)]           # smallest, but slower
    chosen, why = pick_layout(rows, [1 / 3072])
    assert chosen["layout"] == "float_zip_window" and "float_rle" in why
    assert 5200 <= 4500 * BYTES_BUDGET < 90_000
    # a glove with coarse levels (1/255) lets half compete, and it is the fastest
    assert pick_layout(rows, [1 / 255])[0]["layout"] == "half_fast"
    assert pick_layout(rows, [None])[0]["layout"] == "float_zip_window"     # no stated step: exact only
    assert pick_layout([rows[0]], [None]) == (None, "no variant is exact for every glove")
    # a half row whose sample maps happened to round exactly is still half: not exact for a 1/3072 glove
    lucky = _row("half_lucky", "half", 0.1, 1000, 0.0)
    assert pick_layout(rows + [lucky], [1 / 3072])[0]["layout"] == "float_zip_window"
