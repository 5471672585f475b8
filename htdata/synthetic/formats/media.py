"""Shared pieces of the source-format writers: RGB checks, JPEG and H.264 encoding, JSON Lines."""

from __future__ import annotations

import json
import zlib
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np


def seed_of(text: str) -> int:
    """Deterministic per-clip seed (side data must not depend on run order)."""
    return zlib.crc32(text.encode("utf-8"))


def encode_jpeg(rgb: np.ndarray, quality: int, *, swap_rb: bool, where: str) -> bytes:
    import cv2

    check_rgb_frame(rgb, where)
    # cv2 encodes its input as BGR. Passing the RGB array unchanged therefore
    # stores R and B swapped, which is exactly the release's quirk.
    bgr_or_swapped = rgb if swap_rb else rgb[..., ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr_or_swapped), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"{where}: JPEG encoding failed")
    return buf.tobytes()


def check_rgb_frame(frame: np.ndarray, where: str) -> None:
    if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        got = getattr(frame, "shape", type(frame).__name__), getattr(frame, "dtype", "")
        raise ValueError(f"{where}: expected an HxWx3 uint8 RGB frame, got {got}")


def write_h264(path: Path, frames: Iterable[np.ndarray], *, fps: float = 30.0, size: tuple[int, int] | None = None) -> int:
    """Encode RGB uint8 frames to an H.264 (libx264, yuv420p) MP4; return the frame count.

    `size` = (width, height) fixes the frame size; otherwise the first frame
    sets it. A zero-frame video is written as a valid container with an
    empty video stream (needs `size`, default 640x480).
    """
    import av

    path = Path(path)
    rate = Fraction(fps).limit_denominator(1001)
    container = av.open(str(path), mode="w")
    try:
        stream = container.add_stream("libx264", rate=rate)
        stream.pix_fmt = "yuv420p"
        stream.options = {"preset": "veryfast", "crf": "20"}
        count = 0
        frames_it = iter(frames)
        first = next(frames_it, None)
        width, height = size if size is not None else ((first.shape[1], first.shape[0]) if first is not None else (640, 480))
        if width % 2 or height % 2:
            raise ValueError(f"{path}: H.264 yuv420p needs even frame sizes, got {width}x{height}")
        stream.width, stream.height = int(width), int(height)
        container.start_encoding()  # writes the header even when no frame follows
        if first is not None:
            for frame in _chain_one(first, frames_it):
                check_rgb_frame(frame, f"{path} frame {count}")
                if frame.shape[:2] != (height, width):
                    raise ValueError(f"{path} frame {count}: size {frame.shape[1]}x{frame.shape[0]} != {width}x{height}")
                vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
                vf.pts = count
                vf.time_base = 1 / rate
                for packet in stream.encode(vf):
                    container.mux(packet)
                count += 1
        for packet in stream.encode():
            container.mux(packet)
    finally:
        container.close()
    return count


def _chain_one(first, rest: Iterator) -> Iterator:
    yield first
    yield from rest


def write_json_lines(path: Path, rows: Iterable[dict]) -> None:
    with open(path, "w", encoding="utf-8") as f:
        for row in rows:
            f.write(json.dumps(row, separators=(",", ":")))
            f.write("\n")
