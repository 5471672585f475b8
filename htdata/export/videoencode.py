"""An mp4 of 224x224 RGB frames with explicit presentation times (PyAV, libx264 or SVT-AV1)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from htdata.errors import DatasetError
from htdata.format.canvas import CANVAS

VIDEO_TIME_BASE = Fraction(1, 90000)   # mp4's usual clock: 11 us steps, well inside LeRobot's 1e-4 s tolerance


class VideoWriter:
    """One mp4 of 224x224 RGB frames with explicit pts (seconds from the episode's first frame)."""

    def __init__(self, path: Path, fps: int, codec: str, crf: int, gop: int):
        """Open `path` for writing (its folder is created).

        Args:
            path: the mp4 to write.
            fps: the stream's nominal rate (the frames' times are their own, `add`'s `t_s`).
            codec: "libx264" or "libsvtav1".
            crf: the encoder's constant rate factor (quality).
            gop: frames between keyframes.
        """
        import av

        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.container = av.open(str(path), "w", format="mp4")
        self.stream = self.container.add_stream(codec, rate=fps)
        self.stream.width = self.stream.height = CANVAS
        self.stream.pix_fmt = "yuv420p"
        self.stream.codec_context.time_base = VIDEO_TIME_BASE
        self.stream.options = {"crf": str(crf), "g": str(gop)} if codec == "libx264" else \
            {"crf": str(crf), "g": str(gop), "preset": "10"}
        self.last_pts = -1
        self._av = av

    def add(self, rgb: np.ndarray, t_s: float, where: str) -> None:
        """Encode one frame.

        Args:
            rgb: (224, 224, 3) uint8 RGB.
            t_s: its time in seconds from the episode's first frame.
            where: names the frame in an error.

        Raises:
            ValueError: `t_s` does not come after the previous frame's (on the 1/90000 s clock).
        """
        pts = int(round(t_s / VIDEO_TIME_BASE))
        if pts <= self.last_pts:
            raise DatasetError(f"{where}: timestamp {t_s:.6f} s does not come after the previous frame's")
        self.last_pts = pts
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts, frame.time_base = pts, VIDEO_TIME_BASE
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def close(self) -> None:
        """Flush the encoder and close the file."""
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()


