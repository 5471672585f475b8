"""tactilecodec.to_half (cv2 F16C conversion) must equal numpy's astype(float16) bit for bit,
so EXR members hold the very half bits of the numpy path."""

from __future__ import annotations

import io

import numpy as np
import OpenEXR
import pytest

from htdata.format.tactilecodec import encode_exr, encode_tactile, to_half


def numpy_half_bits(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return np.ascontiguousarray(x, dtype=np.float16).view(np.uint16)


EDGES = np.array([0.0, -0.0, 1.0, 1 + 1e-3, 0.99999994, 2.0**-14, np.nextafter(2.0**-14, 0),
                  2.0**-24, 2.0**-25, 2.0**-25 * 1.0001, 3 * 2.0**-26, -3e-8, 65504, 65519, 65520, 1e6,
                  -1e6, np.inf, -np.inf, np.nan], dtype=np.float32)


def test_edge_values_match_numpy_bit_for_bit():
    x = EDGES.reshape(4, 5)
    got = to_half(x)
    assert got.dtype == np.float16 and got.flags.c_contiguous and got.shape == x.shape
    assert np.array_equal(got.view(np.uint16), numpy_half_bits(x))


def test_every_rounding_boundary_in_unit_interval():
    # float32 values around every half-way point between adjacent halves in [0, 1]
    halves = np.arange(0, 0x3C01, dtype=np.uint16).view(np.float16).astype(np.float64)
    mids = ((halves[:-1] + halves[1:]) / 2).astype(np.float32)
    x = np.concatenate([mids, np.nextafter(mids, 0), np.nextafter(mids, 2)])
    x = x[: x.size // 64 * 64].reshape(-1, 64)
    assert np.array_equal(to_half(x).view(np.uint16), numpy_half_bits(x))


def test_random_bit_patterns_match_numpy():
    rng = np.random.default_rng(0)
    x = rng.integers(0, 2**32, size=(512, 512), dtype=np.uint64).astype(np.uint32).view(np.float32)
    got = to_half(x).view(np.uint16)
    want = numpy_half_bits(x)
    nan = np.isnan(x)
    assert np.array_equal(got[~nan], want[~nan])
    assert np.isnan(to_half(x)[nan]).all()


@pytest.mark.parametrize("x", [np.zeros((0, 4), np.float32), np.ones((3,), np.float32),
                               np.ones((2, 3, 4), np.float32), np.ones((4, 4), np.float64),
                               np.ones((8, 8), np.float32)[:, ::2]])
def test_other_shapes_and_dtypes_fall_back_to_numpy(x):
    got = to_half(x)
    assert got.dtype == np.float16 and got.shape == x.shape and got.flags.c_contiguous
    assert np.array_equal(got.view(np.uint16), numpy_half_bits(x))


def _numpy_path_exr(m: np.ndarray) -> bytes:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    buf = io.BytesIO()
    OpenEXR.File(header, {"Y": np.ascontiguousarray(m, dtype=np.float16)}).write(buf)
    return buf.getvalue()


def test_exr_bytes_identical_to_numpy_conversion():
    rng = np.random.default_rng(1)
    m = rng.random((224, 224), dtype=np.float32)
    m[m < 0.6] = 0.0                       # sparse contact, like real maps
    m[0, :8] = [0.0, 1.0, 2.0**-24, 2.0**-25, 1e-7, 6e-5, 0.5, 0.99999994]
    assert encode_exr(m, binding=True) == _numpy_path_exr(m)
    # the dataset's ZIP writer (htdata/format/exrzip.py) stores the same half bits
    for data in (encode_exr(m), encode_tactile(m)):
        stored = OpenEXR.File(io.BytesIO(data)).channels()["Y"].pixels
        assert stored.dtype == np.float16 and np.array_equal(stored.view(np.uint16), numpy_half_bits(m))
    # float32 storage is untouched by the fast path
    assert encode_exr(m, pixel_type=np.float32) != encode_exr(m)
