"""The on-disk format table (htdata/format/table.py): one row per member, exact round trips."""

import numpy as np
import pytest

from htdata.format.table import (
    HANDS,
    INDEX_DTYPE,
    LEGACY_INDEX_DTYPE,
    MEMBER_ORDER,
    MEMBERS,
    SIZE_FIELDS,
    CodecSettings,
    bend_member,
    decode_sample,
    encode_sample,
    raw_member,
    tactile_member,
)


def test_member_order_and_index_columns_are_the_published_format():
    # Changing either breaks every dataset already written: append members, never reorder.
    assert MEMBER_ORDER == ("json", "rgb.jpg", "tactile_left.exr", "tactile_right.exr",
                            "bend_left.npy", "bend_right.npy", "raw_left.npy", "raw_right.npy")
    assert INDEX_DTYPE.names == ("shard", "offset", "episode", "frame", "size_json", "size_rgb",
                                 "size_tactile_left", "size_tactile_right", "size_bend_left", "size_bend_right",
                                 "size_raw_left", "size_raw_right")
    assert INDEX_DTYPE.itemsize == 52
    # formats 1 and 2: the same columns without the raw ones (converted on load)
    assert LEGACY_INDEX_DTYPE.names == INDEX_DTYPE.names[:-2] and LEGACY_INDEX_DTYPE.itemsize == 44
    assert [SIZE_FIELDS[s] for s in MEMBER_ORDER] == list(INDEX_DTYPE.names[4:])
    assert {m.hand for m in MEMBERS if m.hand} == set(HANDS)


def test_hand_member_names():
    assert tactile_member("left") == "tactile_left.exr" and bend_member("right") == "bend_right.npy"
    assert raw_member("left") == "raw_left.npy"
    with pytest.raises(ValueError, match="hand 'middle'"):
        tactile_member("middle")


def sample(hands=HANDS, bend=True):
    rng = np.random.default_rng(1)
    tactile = {h: np.zeros((224, 224), np.float32) for h in hands}
    for m in tactile.values():
        m[50:60, 70:90] = 0.5   # exact in float16
    out = {"meta": {"key": "ep__000000", "frame_index": 0},
           "rgb": rng.integers(0, 255, (224, 224, 3), dtype=np.uint8),
           "tactile": tactile}
    if bend:
        out["bend"] = {h: rng.random(7).astype(np.float32) for h in hands}
        # raw rows in the source dtype: integer counts, or floats with NaN (stored as read)
        out["raw"] = {"left": rng.integers(0, 1023, (3, 16, 16)).astype(np.uint16)} if "left" in hands else {}
        if "right" in hands:
            out["raw"]["right"] = np.where(rng.random((2, 21, 21)) < 0.1, np.nan, rng.random((2, 21, 21))
                                           ).astype(np.float32)
    return out


def test_encode_decode_round_trip_is_exact_for_lossless_members():
    s = sample()
    members = encode_sample(s, CodecSettings(), "ep__000000")
    assert tuple(members) == MEMBER_ORDER
    back = decode_sample(members, "ep__000000")
    assert back["meta"] == s["meta"]
    for h in HANDS:
        assert np.array_equal(back["tactile"][h], s["tactile"][h])
        assert np.array_equal(back["bend"][h], s["bend"][h]) and back["bend"][h].dtype == np.float32
        assert back["raw"][h].dtype == s["raw"][h].dtype and back["raw"][h].tobytes() == s["raw"][h].tobytes()
    assert back["rgb"].shape == (224, 224, 3)   # JPEG: lossy by design
    # deterministic bytes: same sample, same members
    assert encode_sample(s, CodecSettings(), "x") == members


def test_absent_members_are_absent_and_settings_are_used():
    s = sample(hands=("right",), bend=False)
    members = encode_sample(s, CodecSettings(tactile_compression="none", rgb_quality=50), "k")
    assert tuple(members) == ("json", "rgb.jpg", "tactile_right.exr")
    assert len(members["tactile_right.exr"]) > 224 * 224 * 2      # uncompressed half
    back = decode_sample(members, "k")
    assert back["tactile"].keys() == {"right"} and back["bend"] == {}


def test_decode_errors_name_the_member():
    with pytest.raises(ValueError, match=r"ep__000003\.tactile_left\.exr"):
        decode_sample({"tactile_left.exr": b"not an exr"}, "ep__000003")
    with pytest.raises(ValueError, match="unknown member 'depth.png'"):
        decode_sample({"depth.png": b"x"}, "ep__000003")
    with pytest.raises(ValueError, match=r"ep__000004\.json"):
        decode_sample({"json": b"{not json"}, "ep__000004")


def test_every_readable_format_version_has_its_index_dtype_and_loads_as_the_current_one():
    import io

    from htdata.format.table import INDEX_DTYPES, READABLE_FORMAT_VERSIONS, index_dtype
    from htdata.store.indexfile import IndexDtypeError, parse_index

    assert set(INDEX_DTYPES) == set(READABLE_FORMAT_VERSIONS) and INDEX_DTYPE == index_dtype(max(INDEX_DTYPES))
    for version, dtype in INDEX_DTYPES.items():
        # a version's columns are the head plus the members it had, in member order
        assert dtype.names[4:] == tuple(m.column for m in MEMBERS if m.since <= version)
        rows = np.zeros(3, dtype=dtype)
        rows["frame"] = [0, 1, 2]
        rows["size_json"] = [10, 11, 12]
        buf = io.BytesIO()
        np.save(buf, rows)
        loaded = parse_index(buf.getvalue(), f"v{version} index")
        assert loaded.dtype == INDEX_DTYPE
        assert list(loaded["frame"]) == [0, 1, 2] and list(loaded["size_json"]) == [10, 11, 12]
        for name in set(INDEX_DTYPE.names) - set(dtype.names):
            assert not loaded[name].any()      # members the version did not have: absent
    buf = io.BytesIO()
    np.save(buf, np.zeros(2, dtype=[("shard", "<u4"), ("offset", "<u8")]))
    with pytest.raises(IndexDtypeError, match="index dtype"):
        parse_index(buf.getvalue(), "odd index")
