"""htdata-native writer: recording.json + ego video (or JPEG frames) + per-hand tactile npz (docs/NATIVE_FORMAT.md)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from htdata.resources import validate_json
from htdata.synthetic.formats.media import check_rgb_frame, write_h264

NATIVE_FORMAT = "htdata-native"
NATIVE_FORMAT_VERSION = 1


@dataclass
class NativeHand:
    layout: str                  # a registered layout id, e.g. "opentouch_right_16x16"
    values: np.ndarray           # (M,H,W) float32 raw glove units, H,W = the layout's grid
    timestamps_ns: np.ndarray    # (M,) int64 on the glove's OWN clock, at its own rate
    clock_offset_ns: int = 0     # added to timestamps_ns to bring them onto the video clock
    dtype: str = "float32"       # stored dtype of `values` (a raw-count glove records float16)


@dataclass
class NativeRecording:
    task: str
    scene: str
    video_frames: Iterable[np.ndarray]   # egocentric RGB uint8 HxWx3, streamed
    video_timestamps_ns: np.ndarray      # (N,) int64 on the video clock, one per frame
    hands: dict[str, NativeHand]         # "left" / "right" -> hand data
    operator: str = ""
    notes: str = ""
    video_storage: str = "mp4"           # "mp4" -> ego.mp4 ; "jpeg" -> frames/000000.jpg ... ; "none": glove only
    jpeg_quality: int = 90
    extra: dict = field(default_factory=dict)  # free-form, stored under recording.json "extra"

    def validate(self) -> None:
        if self.video_storage not in ("mp4", "jpeg", "none"):
            raise ValueError(f"video_storage must be 'mp4', 'jpeg' or 'none', got {self.video_storage!r}")
        ts = np.asarray(self.video_timestamps_ns)
        if ts.ndim != 1 or not np.issubdtype(ts.dtype, np.integer):
            raise ValueError(f"video_timestamps_ns must be a 1-D integer array, got {ts.dtype} {ts.shape}")
        if not self.hands:
            raise ValueError("a native recording needs at least one hand")
        for hand, h in self.hands.items():
            if hand not in ("left", "right"):
                raise ValueError(f"hand must be 'left' or 'right', got {hand!r}")
            values, hts = np.asarray(h.values), np.asarray(h.timestamps_ns)
            if values.ndim != 3 or hts.shape != (values.shape[0],):
                raise ValueError(f"hand {hand}: values (M,H,W) and timestamps_ns (M,) disagree: {values.shape} vs {hts.shape}")


def _median_fps(ts_ns: np.ndarray) -> float:
    d = np.diff(np.sort(np.asarray(ts_ns, dtype=np.int64)))
    d = d[d > 0]
    return float(1e9 / np.median(d)) if d.size else 30.0


def write_native_recording(folder: Path, rec: NativeRecording) -> None:
    """Write a native recording folder: recording.json, video, per-hand tactile npz."""
    import cv2


    rec.validate()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    video_ts = np.asarray(rec.video_timestamps_ns, dtype=np.int64)
    if rec.video_storage == "none":   # a glove-only recording: no "video" in recording.json
        video = None
    elif rec.video_storage == "mp4":
        np.save(folder / "ego_timestamps.npy", video_ts)
        write_h264(folder / "ego.mp4", rec.video_frames, fps=_median_fps(video_ts))
        video = {"file": "ego.mp4", "timestamps": "ego_timestamps.npy"}
    else:
        np.save(folder / "ego_timestamps.npy", video_ts)
        frames_dir = folder / "frames"
        frames_dir.mkdir(exist_ok=True)
        for i, frame in enumerate(rec.video_frames):
            check_rgb_frame(frame, f"{folder} frame {i}")
            ok = cv2.imwrite(str(frames_dir / f"{i:06d}.jpg"), np.ascontiguousarray(frame[..., ::-1]),
                             [cv2.IMWRITE_JPEG_QUALITY, int(rec.jpeg_quality)])
            if not ok:
                raise ValueError(f"{frames_dir}/{i:06d}.jpg: JPEG write failed")
        video = {"frames_dir": "frames", "timestamps": "ego_timestamps.npy"}

    hands = {}
    for hand, h in sorted(rec.hands.items()):
        name = f"tactile_{hand}.npz"
        np.savez(folder / name, values=np.asarray(h.values, dtype=h.dtype),
                 timestamps_ns=np.asarray(h.timestamps_ns, dtype=np.int64))
        hands[hand] = {"layout": h.layout, "file": name, "clock_offset_ns": int(h.clock_offset_ns)}

    doc = {
        "format": NATIVE_FORMAT,
        "format_version": NATIVE_FORMAT_VERSION,
        "task": rec.task,
        "scene": rec.scene,
        "operator": rec.operator,
        "notes": rec.notes,
        "hands": hands,
    }
    if video is not None:
        doc["video"] = video
    if rec.extra:
        doc["extra"] = rec.extra
    validate_json(doc, "recording", where=str(folder / "recording.json"))
    (folder / "recording.json").write_text(json.dumps(doc, indent=1))
