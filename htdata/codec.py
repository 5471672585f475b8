"""Tactile map and RGB frame codecs, and the tactile value rule.

Stored format (DESIGN.md "Value rule"): tactile maps are float32 in [0,1],
written as single-channel ("Y") OpenEXR HALF, ZIP by default; RGB frames are
JPEG. Everything works in memory (BytesIO), so tar members need no temp files.

float16 facts that matter for [0,1] maps (checked in tests/test_codec.py):
- 0.0 and 1.0 are exact; spacing just below 1.0 is 2**-11, so the round-trip
  error on [0,1] is at most 2**-12 ~= 2.44e-4 (round to nearest).
- The smallest positive subnormal is 2**-24 ~= 5.96e-8; anything below half
  of it flushes to 0. Relative precision near zero is kept (unlike fixed point).
- The largest finite half is 65504; the value rule rejects anything > 1+1e-3
  long before that, so overflow to Inf cannot happen on stored maps.

`TACTILE_CODECS` is a registry of alternatives measured by the benchmark
(`codec_benchmark`); only the default EXR half ZIP is used for datasets.
"""

from __future__ import annotations

import io
import time
from typing import Callable

import cv2
import numpy as np
import OpenEXR

CANVAS = 224
MAP_SHAPE = (CANVAS, CANVAS)
# Resampling round-off tolerated (and clipped) outside [0,1]; see the value rule.
ROUND_OFF = 1e-3
EXR_CHANNEL = "Y"

_EXR_COMPRESSIONS = {
    "zip": OpenEXR.ZIP_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "htj2k256": OpenEXR.HTJ2K256_COMPRESSION,
    "dwab": OpenEXR.DWAB_COMPRESSION,
    "none": OpenEXR.NO_COMPRESSION,
}


def check_tactile_values(tactile_map: np.ndarray, where: str) -> np.ndarray:
    """Apply the value rule; return a float32 (224,224) map inside [0,1].

    NaN/Inf or values beyond the round-off band raise ValueError naming `where`
    (a sample key or file/episode/frame), so bad input is traceable.
    """
    arr = np.asarray(tactile_map)
    if arr.shape != MAP_SHAPE:
        raise ValueError(f"{where}: tactile map has shape {arr.shape}, expected {MAP_SHAPE}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{where}: tactile map has dtype {arr.dtype}, expected float32")
    arr = arr.astype(np.float32, copy=False)
    finite = np.isfinite(arr)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        raise ValueError(
            f"{where}: tactile map has {int((~finite).sum())} non-finite value(s), "
            f"first at row {bad[0]}, col {bad[1]} ({arr[bad[0], bad[1]]})"
        )
    lo, hi = float(arr.min()), float(arr.max())
    if lo < -ROUND_OFF or hi > 1.0 + ROUND_OFF:
        raise ValueError(
            f"{where}: tactile values must lie in [0,1] (round-off of {ROUND_OFF} tolerated); "
            f"got min {lo:.6g}, max {hi:.6g}"
        )
    if lo < 0.0 or hi > 1.0:
        arr = np.clip(arr, 0.0, 1.0)
    return arr


def to_half(values: np.ndarray) -> np.ndarray:
    """float -> contiguous float16, bit-identical to numpy's `astype(np.float16)`.

    numpy converts element by element (~0.4 ms per 224x224 map here, a third
    of the EXR encode); cv2 uses the CPU's F16C instructions (~0.05 ms). Both
    round to nearest even, keep subnormals, -0.0, NaN, and overflow to +-Inf
    (checked exhaustively over [0,1] and on random float32 bit patterns;
    tests/test_codec_half.py keeps the edge cases). cv2 takes 2-D float32
    only; anything else goes through numpy.
    """
    arr = np.asarray(values)
    if arr.dtype == np.float32 and arr.ndim == 2 and arr.size:
        return cv2.multiply(np.ascontiguousarray(arr), 1.0, dtype=cv2.CV_16F)
    return np.ascontiguousarray(arr, dtype=np.float16)


def encode_exr(tactile_map: np.ndarray, compression: str = "zip", pixel_type=np.float16) -> bytes:
    """Raw EXR writer (no value rule): one channel "Y" of `pixel_type`."""
    if compression not in _EXR_COMPRESSIONS:
        raise ValueError(f"unknown EXR compression {compression!r}; known: {sorted(_EXR_COMPRESSIONS)}")
    header = {"compression": _EXR_COMPRESSIONS[compression], "type": OpenEXR.scanlineimage}
    if np.dtype(pixel_type) == np.float16:
        pixels = to_half(tactile_map)
    else:
        pixels = np.ascontiguousarray(tactile_map, dtype=pixel_type)
    buf = io.BytesIO()
    OpenEXR.File(header, {EXR_CHANNEL: pixels}).write(buf)
    return buf.getvalue()


def decode_exr(data: bytes) -> np.ndarray:
    """Read channel "Y" of an in-memory EXR as float32."""
    channels = OpenEXR.File(io.BytesIO(data)).channels()
    if EXR_CHANNEL not in channels:
        raise ValueError(f"EXR has no channel {EXR_CHANNEL!r} (channels: {sorted(channels)})")
    return np.asarray(channels[EXR_CHANNEL].pixels, dtype=np.float32)


def encode_tactile(tactile_map: np.ndarray, compression: str = "zip", where: str = "tactile map") -> bytes:
    """Value rule + EXR HALF, channel "Y" (the dataset format)."""
    return encode_exr(check_tactile_values(tactile_map, where), compression, np.float16)


def decode_tactile(data: bytes, where: str = "tactile map") -> np.ndarray:
    """EXR bytes -> float32 (224,224) map."""
    arr = decode_exr(data)
    if arr.shape != MAP_SHAPE:
        raise ValueError(f"{where}: decoded tactile map has shape {arr.shape}, expected {MAP_SHAPE}")
    return arr


def encode_png16(tactile_map: np.ndarray) -> bytes:
    """16-bit fixed point PNG of a [0,1] map (bench alternative)."""
    arr = check_tactile_values(tactile_map, "png16")
    ok, buf = cv2.imencode(".png", np.round(arr * 65535.0).astype(np.uint16))
    if not ok:
        raise ValueError("cv2 failed to encode a 16-bit PNG")
    return buf.tobytes()


def decode_png16(data: bytes) -> np.ndarray:
    # IMREAD_UNCHANGED: without it cv2 returns uint8.
    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.dtype != np.uint16:
        raise ValueError("not a 16-bit PNG")
    return arr.astype(np.float32) / 65535.0


def _exr_codec(compression: str, pixel_type) -> tuple[Callable, Callable]:
    def encode(tactile_map: np.ndarray) -> bytes:
        return encode_exr(check_tactile_values(tactile_map, f"exr {compression}"), compression, pixel_type)

    return encode, decode_exr


TACTILE_CODECS: dict[str, tuple[Callable[[np.ndarray], bytes], Callable[[bytes], np.ndarray]]] = {
    "exr_half_zip": _exr_codec("zip", np.float16),
    "exr_half_piz": _exr_codec("piz", np.float16),
    "exr_half_htj2k256": _exr_codec("htj2k256", np.float16),
    "exr_float_zip": _exr_codec("zip", np.float32),
    "png16": (encode_png16, decode_png16),
    "exr_half_dwab_lossy": _exr_codec("dwab", np.float16),
}

# What the dataset uses; recorded in the manifest's "codec" section.
DEFAULT_CODEC_INFO = {
    "tactile": {"format": "exr", "channel": EXR_CHANNEL, "pixel_type": "half", "compression": "zip",
                "shape": list(MAP_SHAPE), "range": [0.0, 1.0]},
    "rgb": {"format": "jpeg", "quality": 95, "shape": [CANVAS, CANVAS, 3], "channel_order": "RGB"},
}


def encode_rgb(rgb: np.ndarray, quality: int = 95, where: str = "rgb frame") -> bytes:
    """(224,224,3) uint8 RGB -> JPEG bytes. cv2 expects BGR, so convert first."""
    arr = np.asarray(rgb)
    if arr.shape != (CANVAS, CANVAS, 3) or arr.dtype != np.uint8:
        raise ValueError(f"{where}: expected (224,224,3) uint8 RGB, got {arr.shape} {arr.dtype}")
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(arr, cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"{where}: JPEG encoding failed")
    return buf.tobytes()


def decode_rgb(data: bytes, where: str = "rgb frame") -> np.ndarray:
    """JPEG bytes -> (H,W,3) uint8 RGB."""
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{where}: not a decodable JPEG ({len(data)} bytes)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def codec_benchmark(maps: np.ndarray, codecs: dict | None = None) -> list[dict]:
    """Size, speed and error of each tactile codec over `maps` (N,224,224) in [0,1].

    Returns one dict per codec: bytes_per_frame, encode_ms, decode_ms (per
    frame, mean), max_error, rmse. Timing only; callers must not assert on it.
    """
    maps = np.asarray(maps, dtype=np.float32)
    if maps.ndim != 3 or maps.shape[1:] != MAP_SHAPE or len(maps) == 0:
        raise ValueError(f"codec_benchmark needs (N,224,224) maps with N>0, got {maps.shape}")
    results = []
    for name, (encode, decode) in (codecs or TACTILE_CODECS).items():
        t0 = time.perf_counter()
        blobs = [encode(m) for m in maps]
        t1 = time.perf_counter()
        decoded = np.stack([decode(b) for b in blobs])
        t2 = time.perf_counter()
        err = decoded.astype(np.float64) - maps
        results.append({
            "codec": name,
            "bytes_per_frame": float(np.mean([len(b) for b in blobs])),
            "encode_ms": (t1 - t0) * 1e3 / len(maps),
            "decode_ms": (t2 - t1) * 1e3 / len(maps),
            "max_error": float(np.abs(err).max()),
            "rmse": float(np.sqrt(np.mean(err ** 2))),
        })
    return results
