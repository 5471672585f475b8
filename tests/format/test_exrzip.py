"""The byte-built ZIP EXR writer (htdata/format/exrzip.py) against the OpenEXR binding and OpenImageIO.

Per hard case (all zeros, constant, sparse contact, incompressible floats, values > 1, float16
limits and subnormals, -0.0, NaN/Inf bits, a height that is not a multiple of 16, a 5x3 image, FLOAT
pixels): the header (magic, version, attributes) equals the binding's byte for byte, the offset table
points at the chunks in order, every chunk holds the same first line and the same pixel bytes once a
reader unpacks it (inflated and unfiltered, or as stored when raw). Only the deflate streams may differ
(ISA-L vs the binding's libdeflate), so a chunk one deflater can shrink may be stored raw by the other.
Then OpenEXR and OpenImageIO read our file back bit for bit.
"""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import OpenEXR
import pytest
from isal import isal_zlib

from htdata.format.exrzip import DEFLATE_LEVEL, LINES_PER_CHUNK, encode_zip_exr, zip_filter
from htdata.format.tactilecodec import encode_exr, encode_tactile


def _binding(pixels: np.ndarray) -> bytes:
    buf = io.BytesIO()
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"Y": pixels}).write(buf)
    return buf.getvalue()


def _cases() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    sparse = np.zeros((224, 224), np.float32)
    sparse[6:219, 4:219] = rng.random((213, 215)) * (rng.random((213, 215)) < 0.44)
    limits = np.zeros((224, 224), np.float16)
    limits[0, :10] = [65504.0, -65504.0, 2.0**-24, -(2.0**-24), 2.0**-14, np.nextafter(np.float16(2.0**-14), 0),
                      1.0, 1.0 - 2.0**-11, 1.5, 2.0]
    limits[100] = -0.0
    special = np.zeros((224, 224), np.float16)
    special[50, :4] = [np.nan, np.inf, -np.inf, -0.0]
    special[200:] = np.inf
    return {
        "zeros": np.zeros((224, 224), np.float16),
        "constant": np.full((224, 224), 0.5, np.float16),
        "sparse_half": sparse.astype(np.float16),
        "sparse_float": sparse,
        "noise_float": rng.random((224, 224), dtype=np.float32),       # incompressible: chunks stored raw
        "above_one": (rng.random((224, 224)) * 300.0).astype(np.float16),
        "limits": limits,
        "nan_inf": special,
        "odd_height": rng.random((40, 37)).astype(np.float16),       # last chunk of 8 lines
        "tiny": rng.random((5, 3)).astype(np.float16),
    }


def _parse(data: bytes) -> tuple[bytes, list[int], list[tuple[int, bytes]], tuple[int, int]]:
    """(header bytes incl. the terminating 0, offset table, [(first line, chunk data)], (height, width))."""
    assert data[:4] == b"\x76\x2f\x31\x01" and struct.unpack_from("<i", data, 4)[0] == 2
    at, window = 8, None
    while data[at] != 0:
        name_end = data.index(b"\0", at)
        type_end = data.index(b"\0", name_end + 1)
        size = struct.unpack_from("<i", data, type_end + 1)[0]
        if data[at:name_end] == b"dataWindow":
            x0, y0, x1, y1 = struct.unpack_from("<4i", data, type_end + 5)
            window = (y1 - y0 + 1, x1 - x0 + 1)
        at = type_end + 5 + size
    head = data[:at + 1]
    n = -(-window[0] // LINES_PER_CHUNK)
    offsets = list(struct.unpack_from(f"<{n}Q", data, len(head)))
    chunks = []
    for off in offsets:
        y, size = struct.unpack_from("<ii", data, off)
        chunks.append((y, data[off + 8:off + 8 + size]))
    return head, offsets, chunks, window


def _pixel_bytes(chunk: bytes, raw_size: int) -> bytes:
    """A chunk's pixel bytes, as a reader gets them: stored as is when its count is the raw size, else
    inflated, the predictor undone (running sum of byte - 128, mod 256) and the two halves interleaved."""
    if len(chunk) == raw_size:
        return chunk
    filtered = np.frombuffer(zlib.decompress(chunk), np.uint8).astype(np.int64)
    filtered[1:] -= 128
    split = (np.cumsum(filtered) % 256).astype(np.uint8)
    half = (raw_size + 1) // 2
    out = np.empty(raw_size, np.uint8)
    out[0::2], out[1::2] = split[:half], split[half:]
    return out.tobytes()


@pytest.mark.parametrize("name", list(_cases()))
def test_same_file_layout_and_chunk_bytes_as_the_binding(name):
    pixels = _cases()[name]
    ours, theirs = encode_zip_exr(pixels), _binding(pixels)
    head, offsets, chunks, (h, w) = _parse(ours)
    b_head, _, b_chunks, _ = _parse(theirs)
    assert head == b_head
    assert offsets[0] == len(head) + 8 * len(offsets)
    assert all(offsets[k + 1] == offsets[k] + 8 + len(chunks[k][1]) for k in range(len(chunks) - 1))
    assert offsets[-1] + 8 + len(chunks[-1][1]) == len(ours)                 # nothing after the last chunk
    row_bytes = w * pixels.itemsize
    for k, ((y, data), (b_y, b_data)) in enumerate(zip(chunks, b_chunks, strict=True)):
        lines = min(LINES_PER_CHUNK, h - y)
        assert y == b_y == k * LINES_PER_CHUNK
        raw_size = lines * row_bytes
        assert _pixel_bytes(data, raw_size) == _pixel_bytes(b_data, raw_size)
        if len(data) == raw_size:       # stored raw only where deflate would not shrink it (the deflaters differ)
            assert len(isal_zlib.compress(zip_filter(np.frombuffer(data, np.uint16)[None])[0], DEFLATE_LEVEL)) >= raw_size
        else:
            assert len(data) < raw_size


@pytest.mark.parametrize("name", list(_cases()))
def test_openexr_and_openimageio_read_it_back_bit_for_bit(tmp_path, name):
    oiio = pytest.importorskip("OpenImageIO")
    pixels = _cases()[name]
    data = encode_zip_exr(pixels)
    bits = np.uint16 if pixels.dtype == np.float16 else np.uint32
    got = OpenEXR.File(io.BytesIO(data)).channels()["Y"].pixels
    assert got.dtype == pixels.dtype and np.array_equal(got.view(bits), pixels.view(bits))
    path = tmp_path / f"{name}.exr"
    path.write_bytes(data)
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        spec = inp.spec()
        read = inp.read_image(0, 0, 0, 1, "half" if pixels.dtype == np.float16 else "float")
        assert read is not None, inp.geterror()
    finally:
        inp.close()
    assert (spec.height, spec.width, list(spec.channelnames)) == (*pixels.shape, ["Y"])
    assert spec.getattribute("compression") == "zip"
    read = np.asarray(read).reshape(pixels.shape)
    assert np.array_equal(read.view(bits), pixels.view(bits))


def test_the_dataset_codec_writes_through_it_and_the_binding_stays_for_the_rest():
    m = _cases()["sparse_half"].astype(np.float32)
    assert encode_tactile(m) == encode_exr(m) == encode_zip_exr(m.astype(np.float16))
    assert encode_tactile(m, pixel_type="float") == encode_zip_exr(m)
    assert encode_exr(m, binding=True) == _binding(m.astype(np.float16))
    assert encode_exr(m, "rle") == _binding_rle(m.astype(np.float16))


def _binding_rle(pixels: np.ndarray) -> bytes:
    buf = io.BytesIO()
    OpenEXR.File({"compression": OpenEXR.RLE_COMPRESSION, "type": OpenEXR.scanlineimage}, {"Y": pixels}).write(buf)
    return buf.getvalue()


def test_zip_filter_is_openexrs_byte_loop():
    """The vectorised filter against OpenEXR's reference loop (ImfZip.cpp), written out in Python."""
    words = np.random.default_rng(3).integers(0, 2**16, size=(3, 50), dtype=np.uint16)
    for row, got in zip(words, zip_filter(words.copy())):
        raw = row.tobytes()
        t = bytearray(raw[0::2] + raw[1::2])
        p = t[0]
        for i in range(1, len(t)):
            d = (t[i] - p + 128 + 256) & 0xFF
            p = t[i]
            t[i] = d
        assert got.tobytes() == bytes(t)


@pytest.mark.parametrize("bad", [np.zeros((0, 4), np.float16), np.zeros((4,), np.float16),
                                 np.zeros((4, 4), np.float64), np.zeros((2, 4, 4), np.float32),
                                 np.zeros((4, 4), ">f2")])          # not native order: the binding writes it
def test_refuses_what_it_cannot_write(bad):
    with pytest.raises(ValueError, match="encode_zip_exr"):
        encode_zip_exr(bad)


def test_a_half_map_is_stored_as_it_is_and_checked_by_its_own_values():
    """The ingest renders a "half" dataset's maps in float16: stored without conversion, the same bytes as the
    float32 map they round from; outside [0,1] they meet the same value rule (NaN/Inf refused, round-off clipped)."""
    m = _cases()["sparse_half"].astype(np.float32)
    assert encode_tactile(m.astype(np.float16)) == encode_tactile(m)
    assert encode_tactile(np.zeros((224, 224), np.float16)) == encode_tactile(np.zeros((224, 224), np.float32))
    edge = np.zeros((224, 224), np.float16)
    edge[3, :3] = [-0.0, 1.0, np.float16(1.0) + np.float16(2.0**-10)]     # -0.0 kept, 1.000977 clipped to 1
    want = edge.astype(np.float32)
    want[3, 2] = 1.0
    assert encode_tactile(edge) == encode_tactile(want)
    for bad, match in ((np.nan, "non-finite"), (np.inf, "non-finite"), (1.5, r"\[0,1\]"), (-0.5, r"\[0,1\]")):
        m16 = np.zeros((224, 224), np.float16)
        m16[7, 9] = bad
        with pytest.raises(ValueError, match=match):
            encode_tactile(m16, where="ep__000001.tactile_left.exr")
    with pytest.raises(ValueError, match="shape"):
        encode_tactile(np.zeros((224, 223), np.float16))
    assert encode_tactile(m.astype(np.float16), pixel_type="float") == encode_tactile(m.astype(np.float16).astype(np.float32),
                                                                                       pixel_type="float")


@pytest.mark.parametrize("bad", ["", "Y\0Z", "x" * 32, 7])
def test_the_writer_refuses_a_channel_name_a_header_cannot_hold(bad):
    from htdata.format.exrzip import encode_zip_exr

    with pytest.raises(ValueError, match="channel name"):
        encode_zip_exr(np.zeros((4, 4), np.float16), channel=bad)
    assert encode_zip_exr(np.zeros((4, 4), np.float16), channel="x" * 31)   # the longest short name
