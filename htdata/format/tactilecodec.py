"""Tactile map codecs and the tactile value rule: what a stored map is and how it is written and read.

Stored format (docs/FORMAT.md "Value rule"): tactile maps are float32 in [0,1],
written as single-channel ("Y") OpenEXR, ZIP by default (written by
htdata/format/exrzip.py: the binding's file layout at a third of its cost;
other compressions by the OpenEXR binding), with HALF or FLOAT pixels: the
pipeline's `[codec] tactile = "auto"` picks the pixel type by the rule in
htdata/glove/codecrule.py (smallest codec keeping every glove's levels).
FLOAT is exact; HALF is NOT lossless (max error 2**-12, below). The decoder
reads either. Everything works in memory (BytesIO), so tar members need no temp files.

float16 facts that matter for [0,1] maps (checked in tests/format/test_codec.py):
- 0.0 and 1.0 are exact; spacing just below 1.0 is 2**-11, so the round-trip
  error on [0,1] is at most 2**-12 ~= 2.44e-4 (round to nearest).
- The smallest positive subnormal is 2**-24 ~= 5.96e-8; anything below half
  of it flushes to 0. Relative precision near zero is kept (unlike fixed point).
- The largest finite half is 65504; the value rule rejects anything > 1+1e-3
  long before that, so overflow to Inf cannot happen on stored maps.

The member registry (which codec a member kind uses) is htdata/format/codec.py.
"""

from __future__ import annotations

import io

import cv2
import numpy as np
import OpenEXR

from htdata.errors import ArgumentError, DatasetError
from htdata.format.canvas import MAP_SHAPE
from htdata.format.exrzip import encode_zip_exr, zip_writable
from htdata.format.imageheader import check_exr_windows

# Resampling round-off tolerated (and clipped) outside [0,1]; see the value rule.
ROUND_OFF = 1e-3
EXR_CHANNEL = "Y"

_EXR_COMPRESSIONS = {
    "zip": OpenEXR.ZIP_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
    "rle": OpenEXR.RLE_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "htj2k256": OpenEXR.HTJ2K256_COMPRESSION,
    "dwab": OpenEXR.DWAB_COMPRESSION,
    "none": OpenEXR.NO_COMPRESSION,
}


def check_tactile_values(tactile_map: np.ndarray, where: str) -> np.ndarray:
    """Apply the value rule; return a float32 (224,224) map inside [0,1].

    Args:
        tactile_map: a (224,224) float map.
        where: names it in errors (a sample key or file/episode/frame), so bad input is traceable.

    Returns:
        The map as float32, round-off within ROUND_OFF outside [0,1] clipped.

    Raises:
        ValueError: another shape, a non-float dtype, NaN/Inf, or values beyond the round-off band.
    """
    arr = np.asarray(tactile_map)
    if arr.shape != MAP_SHAPE:
        raise ValueError(f"{where}: tactile map has shape {arr.shape}, expected {MAP_SHAPE}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{where}: tactile map has dtype {arr.dtype}, expected float32")
    arr = arr.astype(np.float32, copy=False)
    lo, hi = float(arr.min()), float(arr.max())
    if 0.0 <= lo and hi <= 1.0:     # the common case in two passes: NaN fails both tests, Inf one
        return arr
    finite = np.isfinite(arr)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        raise ValueError(
            f"{where}: tactile map has {int((~finite).sum())} non-finite value(s), "
            f"first at row {bad[0]}, col {bad[1]} ({arr[bad[0], bad[1]]})"
        )
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
    tests/format/test_codec_half.py keeps the edge cases). cv2 takes 2-D float32
    only; anything else goes through numpy.

    Args:
        values: any float array.

    Returns:
        The C-contiguous float16 array.
    """
    arr = np.asarray(values)
    if arr.dtype == np.float32 and arr.ndim == 2 and arr.size:
        return cv2.multiply(np.ascontiguousarray(arr), 1.0, dtype=cv2.CV_16F)
    return np.ascontiguousarray(arr, dtype=np.float16)


def covered_window(tactile_map: np.ndarray) -> tuple[int, int, int, int]:
    """The smallest box holding every non-zero pixel.

    Args:
        tactile_map: a 2-D map.

    Returns:
        (x0, y0, x1, y1), inclusive; (0, 0, 0, 0) for an empty map.
    """
    rows, cols = np.flatnonzero(tactile_map.any(axis=1)), np.flatnonzero(tactile_map.any(axis=0))
    if rows.size == 0:
        return 0, 0, 0, 0
    return int(cols[0]), int(rows[0]), int(cols[-1]), int(rows[-1])


def encode_exr(tactile_map: np.ndarray, compression: str = "zip", pixel_type=np.float16,
               window: bool = False, binding: bool = False) -> bytes:
    """Raw EXR writer (no value rule): one channel "Y" of `pixel_type`.

    ZIP (the dataset's compression) is written by htdata/format/exrzip.py: the binding's header, offset
    table and filtered chunk bytes, with ISA-L's deflate streams, ~3x cheaper. Other compressions, a data
    window and `binding=True` (the stored-map layout table's "_binding" rows) go through the OpenEXR binding.

    Args:
        tactile_map: a 2-D map; no value rule is applied (encode_tactile applies it).
        compression: one of "zip", "zips", "rle", "piz", "htj2k256", "dwab", "none".
        pixel_type: np.float16 or np.float32.
        window: store only the data window around the non-zero pixels (the display window stays the
            map's full shape; readers place the window in it, pixels outside read 0). The bench measures it.
        binding: write through the OpenEXR binding even for ZIP (the stored-map layout table's "_binding" rows).

    Returns:
        The EXR file's bytes.

    Raises:
        ArgumentError: an unknown compression.
    """
    if compression not in _EXR_COMPRESSIONS:
        raise ArgumentError(f"unknown EXR compression {compression!r}; known: {sorted(_EXR_COMPRESSIONS)}")
    if np.dtype(pixel_type) == np.float16:
        pixels = to_half(tactile_map)
    else:
        pixels = np.ascontiguousarray(tactile_map, dtype=pixel_type)
    if compression == "zip" and not (window or binding) and zip_writable(pixels):
        return encode_zip_exr(pixels, EXR_CHANNEL)
    header = {"compression": _EXR_COMPRESSIONS[compression], "type": OpenEXR.scanlineimage}
    if window:
        x0, y0, x1, y1 = covered_window(pixels)
        h, w = pixels.shape
        header["dataWindow"], header["displayWindow"] = ((x0, y0), (x1, y1)), ((0, 0), (w - 1, h - 1))
        pixels = np.ascontiguousarray(pixels[y0:y1 + 1, x0:x1 + 1])   # the binding reads a view as if contiguous
    buf = io.BytesIO()
    OpenEXR.File(header, {EXR_CHANNEL: pixels}).write(buf)
    return buf.getvalue()


def decode_exr_pixels(data: bytes, where: str = "EXR", shape: tuple[int, int] = MAP_SHAPE) -> np.ndarray:
    """Channel "Y" of an in-memory EXR in its stored pixel type (float16 or float32 for dataset maps),
    the display window's full canvas: the data window's pixels placed in it by their coordinates, 0 elsewhere.

    The header's windows are checked first (htdata/format/imageheader.py): a display window that is not
    `shape`, or a data window outside it, is refused before a pixel is read (a forged 20000x20000 window
    would cost GBs in the decoder). OpenEXR's own exceptions name no file: they are re-raised as a
    DatasetError naming `where`.

    Args:
        data: the EXR bytes.
        where: names the member in errors.
        shape: the display window the format expects, (H, W).

    Returns:
        (H, W) pixels of the stored type.

    Raises:
        DatasetError: windows other than `shape` (imageheader.check_exr_windows), an undecodable file,
            or no "Y" channel.
    """
    (x0, y0, x1, y1), (dx0, dy0, dx1, dy1) = check_exr_windows(data, shape, where)
    try:
        f = OpenEXR.File(io.BytesIO(data))
        channels = f.channels()
    except Exception as exc:
        raise DatasetError(f"{where}: undecodable EXR ({len(data)} bytes): {exc}") from exc
    if EXR_CHANNEL not in channels:
        raise DatasetError(f"{where}: EXR has no channel {EXR_CHANNEL!r} (channels: {sorted(channels)})")
    pixels = np.asarray(channels[EXR_CHANNEL].pixels)
    if (x0, y0, x1, y1) == (dx0, dy0, dx1, dy1):
        return pixels
    canvas = np.zeros((dy1 - dy0 + 1, dx1 - dx0 + 1), pixels.dtype)
    canvas[y0 - dy0:y1 - dy0 + 1, x0 - dx0:x1 - dx0 + 1] = pixels
    return canvas


def decode_exr(data: bytes, where: str = "EXR") -> np.ndarray:
    """Read channel "Y" of an in-memory EXR as float32.

    Args:
        data: the EXR bytes.
        where: names the member in errors (DatasetError, as decode_exr_pixels).

    Returns:
        The (224,224) pixels as float32.
    """
    return decode_exr_pixels(data, where).astype(np.float32, copy=False)


EXR_PIXEL_TYPES = {"half": np.float16, "float": np.float32}


# float16 bits of 1.0: a half map whose every bit pattern is <= this holds only values in [+0, 1] (a sign,
# NaN or Inf pattern is larger), so it passes the value rule as it is.
_HALF_ONE_BITS = 0x3C00


def encode_tactile(tactile_map: np.ndarray, compression: str = "zip", where: str = "tactile map",
                   pixel_type: str = "half") -> bytes:
    """Value rule + EXR of `pixel_type` ("half" or "float"), channel "Y" (the dataset format).

    A float16 map (the ingest renders a "half" dataset's maps in half) is checked by its own values;
    one inside [0,1] is stored as it is, with no conversion (one max over its bits).

    Args:
        tactile_map: the (224,224) map, float16 or float32, values in [0,1].
        compression: the EXR compression (encode_exr).
        where: names the map in errors.
        pixel_type: "half" or "float" (the dataset's codec.tactile.pixel_type).

    Returns:
        The EXR member's bytes.

    Raises:
        ArgumentError: an unknown pixel type or compression.
        ValueError: the map breaks the value rule (check_tactile_values).
    """
    if pixel_type not in EXR_PIXEL_TYPES:
        raise ArgumentError(f"{where}: unknown EXR pixel type {pixel_type!r}; known: {sorted(EXR_PIXEL_TYPES)}")
    arr = np.asarray(tactile_map)
    if (pixel_type == "half" and arr.dtype == np.float16 and arr.shape == MAP_SHAPE
            and int(arr.view(np.uint16).max()) <= _HALF_ONE_BITS):
        return encode_exr(arr, compression, np.float16)
    return encode_exr(check_tactile_values(arr, where), compression, EXR_PIXEL_TYPES[pixel_type])


def decode_tactile(data: bytes, where: str = "tactile map") -> np.ndarray:
    """EXR bytes -> float32 (224,224) map, checked as served (check_served_maps).

    Args:
        data: the member's bytes.
        where: names the member in errors.

    Returns:
        The map, float32 in [0,1] (give or take ROUND_OFF).

    Raises:
        DatasetError: any decode failure, another shape, or values the format never stores.
    """
    arr = decode_exr(data, where)
    if arr.shape != MAP_SHAPE:
        raise DatasetError(f"{where}: decoded tactile map has shape {arr.shape}, expected {MAP_SHAPE}")
    return check_served_maps(arr, where)


def check_served_maps(maps: np.ndarray, where: str) -> np.ndarray:
    """`maps` ((224,224) or (n,224,224)) when every value is finite and inside the format's [0,1] (give or
    take ROUND_OFF); else a DatasetError (a ValueError) naming `where`.

    A NaN served to a training run poisons its loss silently, and a stored map of 1e38 or -1 (a
    re-sealed member: the writer clips to [0,1]) is a value the format never promised: the loaders
    refuse both here. One sum, min and max per map.

    Args:
        maps: (224,224) or (n,224,224) float maps.
        where: names the sample in errors.

    Returns:
        `maps`, unchanged.

    Raises:
        DatasetError: a NaN/Inf value, or one outside [0,1] by more than ROUND_OFF (the first such map named).
    """
    flat = maps.reshape(-1, maps.shape[-2] * maps.shape[-1])
    with np.errstate(over="ignore", invalid="ignore"):
        sums = flat.sum(axis=1, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(sums))
    def which(k) -> str:
        return "" if maps.ndim == 2 else f" (map {int(k)} of {len(sums)} in this batch)"

    if bad.size:
        raise DatasetError(f"{where}: tactile map holds NaN/Inf values{which(bad[0])}: its raw glove rows are not "
                           f"finite; `htdata validate --deep` lists every such sample")
    low, high = flat.min(axis=1), flat.max(axis=1)
    out = np.flatnonzero((low < -ROUND_OFF) | (high > 1.0 + ROUND_OFF))
    if out.size:
        k = int(out[0])
        raise DatasetError(f"{where}: tactile map holds values {float(low[k]):.6g}..{float(high[k]):.6g}{which(k)}, "
                           f"outside the format's [0,1]: the member was not written by htdata (`htdata validate "
                           f"--deep` lists every such sample)")
    return maps


def encode_png16(tactile_map: np.ndarray) -> bytes:
    """16-bit fixed point PNG of a [0,1] map (bench alternative).

    Args:
        tactile_map: a (224,224) map in [0,1].

    Returns:
        The PNG bytes.

    Raises:
        ValueError: the map breaks the value rule, or cv2 failed to encode.
    """
    arr = check_tactile_values(tactile_map, "png16")
    ok, buf = cv2.imencode(".png", np.round(arr * 65535.0).astype(np.uint16))
    if not ok:
        raise ValueError("cv2 failed to encode a 16-bit PNG")
    return buf.tobytes()


def decode_png16(data: bytes) -> np.ndarray:
    """The [0,1] map an encode_png16 PNG holds (bench alternative).

    Args:
        data: the PNG bytes.

    Returns:
        The map as float32.

    Raises:
        DatasetError: not a 16-bit PNG.
    """
    # IMREAD_UNCHANGED: without it cv2 returns uint8.
    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.dtype != np.uint16:
        raise DatasetError("not a 16-bit PNG")
    return arr.astype(np.float32) / 65535.0
