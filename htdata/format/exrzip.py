"""One-channel scanline OpenEXR with ZIP compression, built byte by byte (the dataset's map writer).

Why: the OpenEXR binding costs ~1 ms of CPU per 224x224 map, most of it
fixed per-call work and the set-up of a fresh deflate compressor for each
16-line chunk (the codec bench's stored-map layout table: exr_half_zip vs
exr_half_zip_binding). This writer lays out the same file itself, about 3x
cheaper, so a glove-only ingest that stores its maps is not bound by the
encoder.

The file, as OpenEXR's spec ("OpenEXR File Layout") and the binding write it:
- magic 76 2f 31 01, version 2 (single-part scanline, no flags);
- header: attributes `name\\0 type\\0 int32 size value`, the very attributes,
  order and values the binding writes for `{"compression": ZIP, "type":
  scanlineimage}` (channels, compression, dataWindow, displayWindow,
  lineOrder, pixelAspectRatio, screenWindowCenter, screenWindowWidth, type),
  then a 0 byte;
- the line offset table: one uint64 file offset per chunk of 16 scanlines;
- the chunks: int32 first line, int32 byte count, data. The data is the
  chunk's pixel bytes (little-endian, line after line) through ZIP's two
  filters, the bytes split into the even- then the odd-indexed ones, then
  each byte but the first replaced by (byte - previous byte + 128) mod 256,
  and then deflated in a zlib stream. A chunk whose stream would not be
  smaller than its pixel bytes is stored as those bytes (a reader takes a
  chunk whose count equals its raw size as uncompressed).

So header, offset table and filtered chunk bytes equal the binding's byte
for byte; only the deflate streams differ (ISA-L's igzip at `DEFLATE_LEVEL`
through python-isal's zlib-compatible `isal_zlib`; the binding bundles
libdeflate, reachable only per call with a fresh compressor each time), so
any zlib inflater (OpenEXR's, OpenImageIO's) gives back the same pixels
(tests/format/test_exrzip.py checks both against the binding and reads
ours back with OpenEXR and OpenImageIO). Pixels are written as given
(no value rule here): NaN, Inf, -0.0 and subnormals keep their bits.
"""

from __future__ import annotations

import struct
import sys
import zlib
from functools import lru_cache

import numpy as np
from isal import isal_zlib

LINES_PER_CHUNK = 16          # ZIP_COMPRESSION: 16 scanlines per chunk (ZIPS would be 1)
# ISA-L level 1: on the raw-count glove's maps ~2x less deflate time than Python's zlib at level 1 and
# ~17% fewer bytes (zlib level 1 was 1.2-1.3x the binding's bytes; ISA-L level 0 is ~3x faster again but
# 1.5x zlib-1's bytes). The deflate is a glove-only ingest's largest cost of storing maps (issue 34: stored
# >= 0.8x the maps = "raw" speed). The stored-map layout table of the codec bench gives the bytes and the
# time of exr_*_zip (this writer) and exr_*_zip_binding side by side.
DEFLATE_LEVEL = 1
_MAGIC_VERSION = b"\x76\x2f\x31\x01" + struct.pack("<i", 2)
_PIXEL_TYPES = {np.dtype(np.float16): 1, np.dtype(np.float32): 2}   # OpenEXR HALF, FLOAT
_ZIP_COMPRESSION = 3


MAX_CHANNEL_NAME = 31   # bytes of a channel name in a header without the long-names flag (OpenEXR's limit)


def _attribute(name: str, type_name: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + type_name.encode() + b"\0" + struct.pack("<i", len(value)) + value


@lru_cache(maxsize=16)
def header(height: int, width: int, channel: str, pixel_type: int) -> bytes:
    """Magic, version and header attributes (ending in the 0 byte) of a `height` x `width` one-channel ZIP image."""
    box = struct.pack("<4i", 0, 0, width - 1, height - 1)
    chlist = channel.encode() + b"\0" + struct.pack("<iB3xii", pixel_type, 0, 1, 1) + b"\0"
    return (_MAGIC_VERSION
            + _attribute("channels", "chlist", chlist)
            + _attribute("compression", "compression", bytes([_ZIP_COMPRESSION]))
            + _attribute("dataWindow", "box2i", box)
            + _attribute("displayWindow", "box2i", box)
            + _attribute("lineOrder", "lineOrder", b"\0")                        # INCREASING_Y
            + _attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0))
            + _attribute("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0))
            + _attribute("screenWindowWidth", "float", struct.pack("<f", 1.0))
            + _attribute("type", "string", b"scanlineimage")
            + b"\0")


@lru_cache(maxsize=16)
def _zero_chunk(nbytes: int) -> bytes:
    """The stored bytes of an all-zero chunk (most chunks of a resting hand's map): deflated once."""
    filtered = np.full(nbytes, 128, np.uint8)
    filtered[0] = 0
    packed = zlib.compress(filtered, 9)         # made once: the smallest stream
    return packed if len(packed) < nbytes else bytes(nbytes)


def zip_filter(words: np.ndarray) -> np.ndarray:
    """(n, m) uint16 words of n chunks (little-endian pixel bytes) -> (n, 2m) uint8: ZIP's two filters.

    The even-indexed bytes of a chunk are its words' low bytes, the odd-indexed ones their high
    bytes (for FLOAT pixels too: a float is two words), so the split is two casts, no strided copy.
    """
    n, m = words.shape
    split = np.empty((n, 2 * m), np.uint8)
    np.copyto(split[:, :m], words, casting="unsafe")     # uint16 -> uint8 keeps the low byte
    np.copyto(split[:, m:], words >> 8, casting="unsafe")
    out = np.empty_like(split)
    out[:, 0] = split[:, 0]
    np.subtract(split[:, 1:], split[:, :-1], out=out[:, 1:])   # uint8: wraps mod 256, as OpenEXR's int -> byte
    out[:, 1:] += 128
    return out


def _chunk_data(words: np.ndarray) -> list[bytes]:
    """The stored data of equal-size chunks (`words`: (n, m) uint16, one chunk's pixel bytes per row)."""
    nbytes = 2 * words.shape[1]
    nonzero = np.flatnonzero(words.any(axis=1))
    data = [_zero_chunk(nbytes)] * len(words)
    if nonzero.size:
        for k, filtered in zip(nonzero.tolist(), zip_filter(words[nonzero])):
            packed = isal_zlib.compress(filtered, DEFLATE_LEVEL)   # releases the GIL: encodepool's threads overlap
            data[k] = packed if len(packed) < nbytes else words[k].tobytes()
    return data


def zip_writable(pixels: np.ndarray) -> bool:
    """Whether `encode_zip_exr` writes `pixels`: a non-empty 2-D float16 or float32 array in native byte
    order, on a little-endian machine (EXR's byte order: the words are written as they lie in memory)."""
    return (sys.byteorder == "little" and pixels.ndim == 2 and 0 not in pixels.shape
            and pixels.dtype in _PIXEL_TYPES)


def encode_zip_exr(pixels: np.ndarray, channel: str = "Y") -> bytes:
    """A (H, W) float16 or float32 array -> the bytes of a one-channel scanline ZIP EXR holding it exactly."""
    name = channel.encode("utf-8") if isinstance(channel, str) else b""
    if not 0 < len(name) <= MAX_CHANNEL_NAME or b"\0" in name:
        # the header stores it NUL-terminated, without the long-names flag: 1..31 bytes, no NUL, or readers
        # would take the rest of the header for the name
        raise ValueError(f"encode_zip_exr: channel name {channel!r} must be 1..{MAX_CHANNEL_NAME} UTF-8 bytes "
                         f"without NUL")
    arr = np.ascontiguousarray(pixels)
    if not zip_writable(arr):
        raise ValueError(f"encode_zip_exr: expected a non-empty 2-D float16/float32 array, got {arr.shape} {arr.dtype}")
    height, width = arr.shape
    words = arr.view(np.uint16).reshape(height, -1)       # a FLOAT pixel is two words
    full = height // LINES_PER_CHUNK * LINES_PER_CHUNK
    data = _chunk_data(words[:full].reshape(full // LINES_PER_CHUNK, -1)) if full else []
    if full < height:
        data += _chunk_data(words[full:].reshape(1, -1))
    head = header(height, width, channel, _PIXEL_TYPES[np.dtype(pixels.dtype)])
    offsets, at = [], len(head) + 8 * len(data)
    for d in data:
        offsets.append(at)
        at += 8 + len(d)
    parts = [head, struct.pack(f"<{len(data)}Q", *offsets)]
    for k, d in enumerate(data):
        parts += [struct.pack("<ii", k * LINES_PER_CHUNK, len(d)), d]
    return b"".join(parts)
