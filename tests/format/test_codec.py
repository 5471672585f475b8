import numpy as np
import pytest

from htdata.benchmarks.codecs import TACTILE_CODECS, codec_benchmark
from htdata.format.codec import decode_rgb, encode_rgb
from htdata.format.tactilecodec import check_tactile_values, decode_tactile, encode_tactile

HALF_MAX_ERR = 2.5e-4  # float16 spacing below 1.0 is 2**-11; round to nearest -> 2**-12


def sparse_map(seed=0):
    rng = np.random.default_rng(seed)
    m = rng.random((224, 224), dtype=np.float32)
    m[rng.random((224, 224)) < 0.8] = 0.0
    m[0, 0], m[0, 1] = 0.0, 1.0
    return m


def test_exr_half_round_trip_error_and_exact_ends():
    m = sparse_map()
    m[1, :] = np.linspace(0, 1, 224, dtype=np.float32)
    out = decode_tactile(encode_tactile(m))
    assert out.dtype == np.float32 and out.shape == (224, 224)
    assert np.abs(out - m).max() <= HALF_MAX_ERR
    assert out[0, 0] == 0.0 and out[0, 1] == 1.0
    assert np.all(out[m == 0] == 0) and np.all(out[m == 1] == 1)


def test_exr_is_half_single_y_channel():
    import io

    import OpenEXR

    f = OpenEXR.File(io.BytesIO(encode_tactile(sparse_map())))
    chans = f.channels()
    assert list(chans) == ["Y"]
    assert chans["Y"].pixels.dtype == np.float16


def test_float16_limits_documented():
    # smallest subnormal 2**-24 survives; below half of it flushes to 0
    m = np.zeros((224, 224), np.float32)
    m[0, 0] = 2.0 ** -24
    m[0, 1] = 2.0 ** -26
    m[0, 2] = 1e-4      # relative precision kept near zero
    out = decode_tactile(encode_tactile(m))
    assert out[0, 0] == pytest.approx(5.96e-8, rel=1e-2)
    assert out[0, 1] == 0.0
    assert abs(out[0, 2] - 1e-4) / 1e-4 < 1e-3
    assert np.finfo(np.float16).max == 65504  # never reached: the value rule stops at 1+1e-3


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -0.5, 1.5, 65504.0, -2e-3])
def test_value_rule_rejects_and_names_where(bad):
    m = sparse_map()
    m[5, 7] = bad
    with pytest.raises(ValueError, match="ep_x__000003"):
        encode_tactile(m, where="ep_x__000003")


def test_round_off_is_clipped():
    m = sparse_map()
    m[2, 2], m[3, 3] = -5e-4, 1.0 + 9e-4
    out = decode_tactile(encode_tactile(m))
    assert out[2, 2] == 0.0 and out[3, 3] == 1.0
    assert check_tactile_values(m, "x").min() == 0.0


@pytest.mark.parametrize("m", [np.zeros((224, 224), np.float32), np.ones((224, 224), np.float32),
                               np.full((224, 224), 0.5, np.float32)])
def test_constant_maps_round_trip_exactly(m):
    assert np.array_equal(decode_tactile(encode_tactile(m)), m)


def test_wrong_shape_and_dtype_rejected():
    with pytest.raises(ValueError, match="shape"):
        encode_tactile(np.zeros((224, 223), np.float32), where="w")
    with pytest.raises(ValueError, match="dtype"):
        encode_tactile(np.zeros((224, 224), np.uint8), where="w")


def test_encoding_is_deterministic():
    m = sparse_map(3)
    assert encode_tactile(m) == encode_tactile(m.copy())


def test_all_registry_codecs_round_trip():
    m = sparse_map(1)
    for name, (enc, dec) in TACTILE_CODECS.items():
        out = dec(enc(m))
        assert out.shape == (224, 224) and out.dtype == np.float32, name
        err = np.abs(out - m).max()
        if name == "exr_float_zip":
            assert err == 0.0
        elif name == "png16":
            assert err <= 0.5 / 65535 + 1e-7
        elif name == "exr_half_dwab_lossy":
            assert err < 0.1
        else:
            assert err <= HALF_MAX_ERR, name


def test_jpeg_keeps_colour_order():
    img = np.zeros((224, 224, 3), np.uint8)
    img[:, :112] = (255, 0, 0)   # pure red left half
    img[:, 112:] = (0, 0, 255)   # pure blue right half
    out = decode_rgb(encode_rgb(img))
    assert out.shape == (224, 224, 3) and out.dtype == np.uint8
    red, blue = out[100, 50].astype(int), out[100, 170].astype(int)
    assert red[0] > 240 and red[1] < 15 and red[2] < 15
    assert blue[2] > 240 and blue[0] < 15 and blue[1] < 15


def test_rgb_input_checked_and_bad_jpeg_rejected():
    with pytest.raises(ValueError, match="224"):
        encode_rgb(np.zeros((10, 10, 3), np.uint8), where="frame 3")
    with pytest.raises(ValueError, match="frame 9"):
        decode_rgb(b"not a jpeg", where="frame 9")


def test_codec_benchmark_reports_every_codec():
    maps = np.stack([sparse_map(i) for i in range(2)])
    res = codec_benchmark(maps)
    assert [r["codec"] for r in res] == list(TACTILE_CODECS)
    for r in res:
        assert r["bytes_per_frame"] > 0 and r["encode_ms"] >= 0 and r["decode_ms"] >= 0
        assert 0 <= r["rmse"] <= r["max_error"]
    by = {r["codec"]: r for r in res}
    assert by["exr_float_zip"]["max_error"] == 0.0
    with pytest.raises(ValueError):
        codec_benchmark(np.zeros((0, 224, 224), np.float32))


def test_encode_npy_is_np_save_byte_for_byte():
    """The cached-header fast path gives np.save's exact bytes, for every order, dtype and shape."""
    import io

    from htdata.format.codec import encode_npy

    def reference(a):
        buf = io.BytesIO()
        np.save(buf, np.asarray(a), allow_pickle=False)
        return buf.getvalue()

    rng = np.random.default_rng(0)
    cases = [rng.random((3, 21, 21)).astype(np.float32), rng.random((1, 16, 16)).astype(np.float16),
             np.arange(7, dtype=np.int64), rng.random((5, 4)).astype(">f4"), np.asfortranarray(rng.random((4, 5))),
             rng.random((4, 5))[:, ::2], rng.random((4, 5)), np.zeros((0, 21, 21), np.float32), np.float32(3.5),
             np.array(True)]
    for a in cases + cases:            # the second pass takes the cached headers
        assert encode_npy(a) == reference(a), (np.asarray(a).dtype, np.shape(a))
