"""RGB preprocessing: source channel order -> RGB, crop to square, resize to 224.

The default is a centre crop to the largest square followed by cv2 INTER_AREA
(the anti-aliased choice for downsampling; cv2 falls back to bilinear when
upsampling, e.g. a 1x1 frame). crop="none" squashes the whole frame instead.
"cubic2x_area" (opt-in, issue #47) resizes by INTER_CUBIC to exactly twice the
target and then by an integer 2x2 INTER_AREA box (cv2's fast path): about half
of INTER_AREA's time at a non-integer ratio, at 0.93-1.07x its mean error
against the bench's reference (bench/REPORT.md, "RGB"); a source square under
twice the target gets plain INTER_AREA.

A source frame is at most MAX_SOURCE_FRAME_PIXELS: a JPEG's size is read from its
header before it is decoded (`decode_jpeg_frame`), a video's from its stream
(htdata/source/adapters/video.py), and a larger one is refused (a 691-byte JPEG
declaring 30000x30000 would otherwise cost 5 GB in the decoder).
"""

from __future__ import annotations

import cv2
import numpy as np

from htdata.errors import ArgumentError
from htdata.format.imageheader import jpeg_size

CROPS = ("center", "none")
INTERPOLATIONS = {
    "area": cv2.INTER_AREA,
    "linear": cv2.INTER_LINEAR,
    "cubic": cv2.INTER_CUBIC,   # uint8 output saturates, so overshoot cannot wrap
    "nearest": cv2.INTER_NEAREST,
    "cubic2x_area": None,       # two steps (resize_cubic2x_area), not one cv2 flag
}
CHANNEL_ORDERS = ("rgb", "bgr")
# 16 megapixels (4096x4096, a 5.3K 5312x2988 action camera): 48 MB decoded. Frames are resized to 224x224,
# so no egocentric camera needs more; a header declaring more is refused before the decoder allocates it.
MAX_SOURCE_FRAME_PIXELS = 1 << 24


def frame_size_error(height: int, width: int) -> str | None:
    """Why a source frame of `height` x `width` is refused (None: it is not)."""
    if height < 1 or width < 1:
        return f"declares {width}x{height} pixels: no image"
    if height * width > MAX_SOURCE_FRAME_PIXELS:
        return (f"declares {width}x{height} pixels ({height * width / 1e6:.0f} Mpx), more than a source frame may "
                f"hold ({MAX_SOURCE_FRAME_PIXELS / 1e6:.1f} Mpx): refused before decoding")
    return None


def decode_jpeg_frame(data) -> np.ndarray:
    """A source JPEG (bytes or uint8 array) -> HxWx3 uint8 as cv2 decodes it (BGR).

    Its size is read from the header first: no frame header, or one beyond MAX_SOURCE_FRAME_PIXELS, is
    refused undecoded. Raises ValueError with the reason (the adapter names file and frame).
    """
    buf = np.frombuffer(data, np.uint8) if isinstance(data, (bytes, bytearray, memoryview)) else np.asarray(data, np.uint8)
    size = jpeg_size(memoryview(np.ascontiguousarray(buf))) if buf.size else None
    if size is None:
        raise ValueError("JPEG does not decode")
    why = frame_size_error(*size)
    if why:
        raise ValueError(f"JPEG {why}")
    img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if img is None or img.ndim != 3:
        raise ValueError("JPEG does not decode")
    return img


def _check_frame(frame, where: str) -> np.ndarray:
    arr = np.asarray(frame)
    if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{where}: expected an HxWx3 uint8 frame, got shape {arr.shape} dtype {arr.dtype}")
    return arr


def to_rgb(frame, channel_order: str = "rgb", where: str = "rgb frame") -> np.ndarray:
    """Reorder channels so the result is RGB (some sources store B and R swapped)."""
    arr = _check_frame(frame, where)
    if channel_order == "rgb":
        return arr
    if channel_order == "bgr":
        return arr[:, :, ::-1]
    raise ArgumentError(f"{where}: channel_order must be one of {CHANNEL_ORDERS}, got {channel_order!r}")


def centre_square(frame: np.ndarray) -> np.ndarray:
    """Largest centred square (view, no copy); odd margins put the extra pixel right/bottom."""
    h, w = frame.shape[:2]
    side = min(h, w)
    y0, x0 = (h - side) // 2, (w - side) // 2
    return frame[y0:y0 + side, x0:x0 + side]


def to_square_224(frame, size: int = 224, crop: str = "center", interpolation: str = "area",
                  where: str = "rgb frame") -> np.ndarray:
    """HxWx3 uint8 -> (size,size,3) uint8, contiguous."""
    arr = _check_frame(frame, where)
    if crop not in CROPS:
        raise ArgumentError(f"{where}: crop must be one of {CROPS}, got {crop!r}")
    if interpolation not in INTERPOLATIONS:
        raise ArgumentError(f"{where}: interpolation must be one of {sorted(INTERPOLATIONS)}, got {interpolation!r}")
    if not isinstance(size, int) or size < 1:
        raise ArgumentError(f"{where}: size must be a positive integer, got {size!r}")
    if crop == "center":
        arr = centre_square(arr)
    if arr.shape[:2] == (size, size):
        return np.ascontiguousarray(arr)
    if interpolation == "cubic2x_area":
        return resize_cubic2x_area(np.ascontiguousarray(arr), size)
    out = cv2.resize(np.ascontiguousarray(arr), (size, size), interpolation=INTERPOLATIONS[interpolation])
    return out


def resize_cubic2x_area(arr: np.ndarray, size: int) -> np.ndarray:
    """INTER_CUBIC to exactly (2*size, 2*size), then the integer 2x2 INTER_AREA box to (size, size); a frame
    under twice the target on either side gets plain INTER_AREA (the cubic step would upsample)."""
    if min(arr.shape[:2]) < 2 * size:
        return cv2.resize(arr, (size, size), interpolation=cv2.INTER_AREA)
    big = cv2.resize(arr, (2 * size, 2 * size), interpolation=cv2.INTER_CUBIC)
    return cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA)
