"""The member codecs' registry (`MEMBER_CODECS`), and the codecs of the members that are not maps.

`MEMBER_CODECS` maps each codec kind named in the member table (htdata/format/table.py) to its
(encoder, decoder): JPEG RGB frames (lossy), PNG label maps, npy raw rows, JSON, and the tactile
maps' EXR (htdata/format/tactilecodec.py: the value rule, the EXR writer and reader). Alternatives
measured by the benchmark live in htdata/benchmarks/codecs.py. Everything works in memory, so tar
members need no temp files. A new codec kind: its encoder and decoder here (or in a module of its
own), one `MEMBER_CODECS` entry, the kind named by a Member row of the table.
"""

from __future__ import annotations

import io
import json
import struct

import cv2
import numpy as np

from htdata._moved import moved_name
from htdata.errors import DatasetError
from htdata.format.canvas import CANVAS, MAP_SHAPE
from htdata.format.imageheader import DeclaredShapeError, jpeg_size
from htdata.format.tactilecodec import EXR_CHANNEL, decode_tactile, encode_tactile

# The manifest's "codec" section before the codec rule's choice is filled in (htdata.glove.codecrule
# CodecChoice.manifest_info replaces the tactile pixel type, codec name and reason).
DEFAULT_CODEC_INFO = {
    "tactile": {"format": "exr", "channel": EXR_CHANNEL, "pixel_type": "half", "compression": "zip",
                "shape": list(MAP_SHAPE), "range": [0.0, 1.0]},
    "rgb": {"format": "jpeg", "quality": 95, "shape": [CANVAS, CANVAS, 3], "channel_order": "RGB"},
}


def encode_rgb(rgb: np.ndarray, quality: int = 95, where: str = "rgb frame") -> bytes:
    """(224,224,3) uint8 RGB -> JPEG bytes. cv2 expects BGR, so convert first.

    Args:
        rgb: the frame, (224,224,3) uint8 in RGB order.
        quality: JPEG quality (the pipeline's `[codec] rgb_quality`).
        where: names the frame in errors.

    Returns:
        The JPEG bytes.

    Raises:
        ValueError: another shape or dtype, or cv2 failed to encode.
    """
    arr = np.asarray(rgb)
    if arr.shape != (CANVAS, CANVAS, 3) or arr.dtype != np.uint8:
        raise ValueError(f"{where}: expected (224,224,3) uint8 RGB, got {arr.shape} {arr.dtype}")
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(arr, cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"{where}: JPEG encoding failed")
    return buf.tobytes()


def decode_rgb(data: bytes, where: str = "rgb frame") -> np.ndarray:
    """JPEG bytes -> (224,224,3) uint8 RGB; a JPEG whose header declares another size is refused
    undecoded: a 691-byte member declaring 30000x30000 costs nothing.

    Args:
        data: the member's bytes.
        where: names the member in errors.

    Returns:
        The frame, (224,224,3) uint8 RGB.

    Raises:
        DeclaredShapeError: the header declares another size (a DatasetError).
        DatasetError: not a decodable JPEG.
    """
    size = jpeg_size(data)
    if size is None:
        raise DatasetError(f"{where}: not a decodable JPEG ({len(data)} bytes)")
    if size != (CANVAS, CANVAS):
        raise DeclaredShapeError(f"{where}: JPEG declares {size[1]}x{size[0]} pixels, expected "
                                 f"{CANVAS}x{CANVAS}: not decoded", size)
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DatasetError(f"{where}: not a decodable JPEG ({len(data)} bytes)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def encode_png_u8(image: np.ndarray, where: str) -> bytes:
    """(224,224) uint8 label/coverage map -> PNG bytes (lossless).

    Args:
        image: the map, (224,224) uint8.
        where: names the map in errors.

    Returns:
        The PNG bytes.

    Raises:
        ValueError: another shape or dtype, or cv2 failed to encode.
    """
    arr = np.asarray(image)
    if arr.shape != MAP_SHAPE or arr.dtype != np.uint8:
        raise ValueError(f"{where}: expected a (224,224) uint8 map, got {arr.shape} {arr.dtype}")
    ok, buf = cv2.imencode(".png", arr)
    if not ok:
        raise ValueError(f"{where}: PNG encoding failed")
    return buf.tobytes()


def decode_png_u8(data: bytes, where: str) -> np.ndarray:
    """PNG bytes -> the 2-D uint8 map encode_png_u8 wrote.

    Args:
        data: the PNG bytes.
        where: names the map in errors.

    Returns:
        The map, as stored (2-D uint8).

    Raises:
        DatasetError: not a single-channel 8-bit PNG.
    """
    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.dtype != np.uint8 or arr.ndim != 2:
        raise DatasetError(f"{where}: not a single-channel 8-bit PNG")
    return arr


_NPY_HEADER_CACHE_MAX = 256

# (dtype, shape) -> np.save's header bytes for a C-ordered array: one per member shape of a dataset, so the
# header dict is formatted once, not for every raw-row / bend member (~2% of an ingest).
_NPY_SAVE_HEADERS: dict[tuple[str, tuple], bytes] = {}


def encode_npy(array: np.ndarray) -> bytes:
    """np.save bytes (no pickle): dtype and shape travel with the data; byte-identical to np.save.

    Args:
        array: any array without Python objects (raw glove rows, bend values).

    Returns:
        The .npy bytes (the header cached per dtype and shape).
    """
    arr = np.asarray(array)
    # np.save writes an F-contiguous (not C) array in Fortran order; anything else as C-order bytes
    fast = not (arr.flags.f_contiguous and not arr.flags.c_contiguous) and not arr.dtype.hasobject
    key = (arr.dtype.str, arr.shape)
    header = _NPY_SAVE_HEADERS.get(key) if fast else None
    if header is None:
        buf = io.BytesIO()
        np.save(buf, arr, allow_pickle=False)
        data = buf.getvalue()
        if fast and len(_NPY_SAVE_HEADERS) < _NPY_HEADER_CACHE_MAX:
            _NPY_SAVE_HEADERS[key] = data[:len(data) - arr.nbytes]
        return data
    return header + arr.tobytes()


# npy header bytes -> (dtype, shape, fortran_order, data offset). Members of one dataset
# share a handful of headers, so np.load's header parsing (ast.literal_eval) runs once per shape.
_NPY_HEADERS: dict[bytes, tuple[np.dtype, tuple, bool, int]] = {}


def decode_npy(data: bytes, where: str = "npy") -> np.ndarray:
    """.npy bytes -> array (a writable copy), exactly what np.load would return.

    Args:
        data: the member's bytes.
        where: names the member in errors.

    Returns:
        The array (its header parsed once per distinct header).

    Raises:
        DatasetError: not an .npy member, a truncated header, or data bytes that disagree with the header.
    """
    if data[:6] != b"\x93NUMPY" or len(data) < 10:
        raise DatasetError(f"{where}: not an .npy member ({len(data)} bytes)")
    if data[6] == 1:
        start = 10 + struct.unpack_from("<H", data, 8)[0]
    elif len(data) >= 12:
        start = 12 + struct.unpack_from("<I", data, 8)[0]
    else:
        raise DatasetError(f"{where}: truncated .npy header")
    header = data[:start]
    meta = _NPY_HEADERS.get(header)
    if meta is None:
        try:
            arr = np.load(io.BytesIO(data), allow_pickle=False)
        except Exception as exc:
            raise DatasetError(f"{where}: unreadable .npy member: {exc}") from exc
        fortran = arr.ndim > 1 and arr.flags.f_contiguous and not arr.flags.c_contiguous
        if len(_NPY_HEADERS) < _NPY_HEADER_CACHE_MAX:
            _NPY_HEADERS[header] = (arr.dtype, arr.shape, fortran, start)
        return arr
    dtype, shape, fortran, start = meta
    count = int(np.prod(shape, dtype=np.int64))
    if len(data) - start != count * dtype.itemsize:
        raise DatasetError(f"{where}: .npy member holds {len(data) - start} data bytes, "
                           f"header says {count * dtype.itemsize}")
    return np.frombuffer(data, dtype, count, start).reshape(shape, order="F" if fortran else "C").copy()


def encode_json(obj) -> bytes:
    """Compact, key-sorted JSON: equal dicts give equal bytes (deterministic shards).

    Args:
        obj: a JSON-serialisable value (a sample's metadata).

    Returns:
        The UTF-8 bytes.
    """
    return json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()


def decode_json(data: bytes, where: str = "json") -> dict:
    """JSON member bytes -> its value.

    Args:
        data: the member's bytes.
        where: names the member in errors.

    Returns:
        The decoded value (a dict for a sample's json member).

    Raises:
        DatasetError: not UTF-8 JSON.
    """
    try:
        return json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{where}: invalid JSON member: {exc}") from exc


# Codec kind (htdata/format/table.py MEMBERS) -> (encode(value, settings, where), decode(data, where));
# `settings` is a format.CodecSettings.
MEMBER_CODECS = {
    "json": (lambda obj, settings, where: encode_json(obj), decode_json),
    "jpeg": (lambda rgb, settings, where: encode_rgb(rgb, settings.rgb_quality, where), decode_rgb),
    "exr": (lambda m, settings, where: encode_tactile(m, settings.tactile_compression, where,
                                                      settings.tactile_pixel_type), decode_tactile),
    "npy": (lambda arr, settings, where: encode_npy(arr), decode_npy),
}


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
