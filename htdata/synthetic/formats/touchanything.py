"""TouchAnything-style writer: one folder per episode (videos, pressure_grids.npz, JSON Lines) + split.json."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from htdata.synthetic.formats.media import seed_of, write_h264, write_json_lines

TA_GRID = 21
TA_VIDEO_SIZE = (640, 480)  # width, height
TA_FPS = 30


@dataclass
class TouchAnythingEpisode:
    left_grid: np.ndarray | None        # (T,21,21) float32 in [0,1], NaN at no-sensor cells
    right_grid: np.ndarray | None       # (T,21,21) AS STORED (mirrored columns)
    chest_frames: Iterable[np.ndarray]  # RGB uint8 480x640x3 at 30 fps (may be a frame or two off T)
    ts_epoch_s: np.ndarray              # (T,) float64 epoch seconds for jq_pressure.json
    sensor_left: np.ndarray | None = None   # (T,256) uint8 raw channels (zeros when None)
    sensor_right: np.ndarray | None = None
    npz_scalars: dict | None = None     # None -> {"grid_size", "num_frames", "tactile_max"}; {} -> none


def _check_ta_episode(ep: TouchAnythingEpisode, where: str) -> int:
    ts = np.asarray(ep.ts_epoch_s)
    if ts.ndim != 1:
        raise ValueError(f"{where}: ts_epoch_s must be 1-D, got shape {ts.shape}")
    t = ts.shape[0]
    for name in ("left_grid", "right_grid"):
        grid = getattr(ep, name)
        if grid is not None and np.asarray(grid).shape != (t, TA_GRID, TA_GRID):
            raise ValueError(f"{where}: {name} must have shape ({t},{TA_GRID},{TA_GRID}), got {np.asarray(grid).shape}")
    for name in ("sensor_left", "sensor_right"):
        raw = getattr(ep, name)
        if raw is not None and np.asarray(raw).shape != (t, 256):
            raise ValueError(f"{where}: {name} must have shape ({t},256), got {np.asarray(raw).shape}")
    return t


def _ta_jq_rows(ep: TouchAnythingEpisode, t: int) -> Iterator[dict]:
    zeros = np.zeros(256, dtype=np.uint8)
    for i in range(t):
        left = zeros if ep.sensor_left is None else np.asarray(ep.sensor_left[i], dtype=np.uint8)
        right = zeros if ep.sensor_right is None else np.asarray(ep.sensor_right[i], dtype=np.uint8)
        yield {
            "ts": float(ep.ts_epoch_s[i]),
            "frame_index": i,
            "sensor_left": left.tolist(),
            "sensor_right": right.tolist(),
        }


def _keypoints(rng: np.random.Generator, n: int, dims: int, scale: float) -> list:
    return np.round(rng.normal(0, scale, (n, dims)), 3).tolist()


def _ta_side_rows(kind: str, ts: np.ndarray, seed: int) -> Iterator[dict]:
    """Small plausible rows for the side-data JSON Lines files (not read by htdata)."""
    rng = np.random.default_rng(seed)
    for i, t in enumerate(ts):
        if kind in ("wilor", "hamer"):
            hand = {"keypoints_2d": (np.array([320.0, 300.0]) + rng.normal(0, 40, (21, 2))).round(1).tolist(),
                    "score": round(float(rng.uniform(0.6, 1.0)), 3)}
            yield {"frame_index": i, "ts": float(t), "left": hand, "right": hand if i % 4 else None}
        elif kind == "rokoko":
            yield {"frame_index": i, "ts": float(t),
                   "left": {"joints": _keypoints(rng, 21, 3, 0.05)},
                   "right": {"joints": _keypoints(rng, 21, 3, 0.05)}}
        else:  # vive
            yield {"frame_index": i, "ts": float(t),
                   "trackers": {"chest": [0.0, 1.4, 0.1, 1.0, 0.0, 0.0, 0.0],
                                "left_wrist": np.round(rng.normal(0, 0.1, 7), 3).tolist(),
                                "right_wrist": np.round(rng.normal(0, 0.1, 7), 3).tolist()}}


def _grey_frames(n: int, value: int) -> Iterator[np.ndarray]:
    w, h = TA_VIDEO_SIZE
    for _ in range(n):
        yield np.full((h, w, 3), value, dtype=np.uint8)


def write_touchanything_episode(
    folder: Path,
    ep: TouchAnythingEpisode,
    *,
    wrist_videos: bool = True,
    wrist_frames: int = 4,
    compress_npz: bool = True,
) -> None:
    """Write one TouchAnything-style episode folder.

    chest.mp4 (H.264 640x480 30 fps yuv420p), left/right.mp4 (real H.264,
    only `wrist_frames` grey frames: htdata never reads them),
    pressure_grids.npz (savez_compressed unless `compress_npz=False`),
    jq_pressure.json and the four side-data JSON Lines files.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    t = _check_ta_episode(ep, str(folder))
    arrays: dict[str, np.ndarray] = {}
    if ep.left_grid is not None:
        arrays["left_pressure_grid"] = np.asarray(ep.left_grid, dtype=np.float32)
    if ep.right_grid is not None:
        arrays["right_pressure_grid"] = np.asarray(ep.right_grid, dtype=np.float32)
    scalars = {"grid_size": TA_GRID, "num_frames": t, "tactile_max": 1.0} if ep.npz_scalars is None else ep.npz_scalars
    arrays.update({k: np.asarray(v) for k, v in scalars.items()})
    (np.savez_compressed if compress_npz else np.savez)(folder / "pressure_grids.npz", **arrays)

    write_json_lines(folder / "jq_pressure.json", _ta_jq_rows(ep, t))
    ts = np.asarray(ep.ts_epoch_s, dtype=np.float64)
    for kind, name in (("wilor", "wilor_hands.json"), ("hamer", "hamer_hands.json"),
                       ("rokoko", "rokoko_hands.json"), ("vive", "vive_poses.json")):
        write_json_lines(folder / name, _ta_side_rows(kind, ts, seed_of(f"{folder.name}/{kind}")))

    write_h264(folder / "chest.mp4", ep.chest_frames, fps=TA_FPS, size=TA_VIDEO_SIZE)
    if wrist_videos:
        write_h264(folder / "left.mp4", _grey_frames(wrist_frames, 96), fps=TA_FPS, size=TA_VIDEO_SIZE)
        write_h264(folder / "right.mp4", _grey_frames(wrist_frames, 160), fps=TA_FPS, size=TA_VIDEO_SIZE)


TA_SPLIT_KEYS = ("train", "val", "test_seen", "test_unseen")


def write_touchanything_split(root: Path, split: dict[str, list[str]]) -> None:
    """Write `root/split.json` with keys train/val/test_seen/test_unseen (missing keys -> [])."""
    unknown = set(split) - set(TA_SPLIT_KEYS)
    if unknown:
        raise ValueError(f"{root}/split.json: unknown split keys {sorted(unknown)}; allowed {TA_SPLIT_KEYS}")
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    doc = {k: [str(p) for p in split.get(k, [])] for k in TA_SPLIT_KEYS}
    (root / "split.json").write_text(json.dumps(doc, indent=1))
