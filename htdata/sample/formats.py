"""Writers for raw recordings in the three source layouts.

Used by the synthetic sample corpus (`htdata sample`) and by the adapter
tests. Each writer reproduces its source's on-disk layout exactly (same
keys, dtypes and quirks), so the adapters are tested against the real
shape of the data:

- OpenTouch-style: one HDF5 per scene, clips under `data/demo_NN`, JPEGs
  stored with R and B swapped, inverted pressure units (3072 = no load).
- TouchAnything-style: one folder per episode with H.264 videos,
  `pressure_grids.npz` (21x21, NaN = no sensor, right grid mirrored),
  `jq_pressure.json` (JSON Lines, epoch seconds) and side-data JSON Lines.
- htdata-native: the project's own format (docs/NATIVE_FORMAT.md).

Frames are taken from iterables and written one at a time, so long
episodes stream to disk.
"""

from __future__ import annotations

import csv
import json
import zlib
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

# --------------------------------------------------------------------------
# shared helpers


def _seed_of(text: str) -> int:
    """Deterministic per-clip seed (side data must not depend on run order)."""
    return zlib.crc32(text.encode("utf-8"))


def _encode_jpeg(rgb: np.ndarray, quality: int, *, swap_rb: bool, where: str) -> bytes:
    import cv2

    _check_rgb_frame(rgb, where)
    # cv2 encodes its input as BGR. Passing the RGB array unchanged therefore
    # stores R and B swapped, which is exactly the release's quirk.
    bgr_or_swapped = rgb if swap_rb else rgb[..., ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr_or_swapped), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"{where}: JPEG encoding failed")
    return buf.tobytes()


def _check_rgb_frame(frame: np.ndarray, where: str) -> None:
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
                _check_rgb_frame(frame, f"{path} frame {count}")
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


def _write_json_lines(path: Path, rows: Iterable[dict]) -> None:
    with open(path, "w", encoding="utf-8") as f:
        for row in rows:
            f.write(json.dumps(row, separators=(",", ":")))
            f.write("\n")


# --------------------------------------------------------------------------
# OpenTouch-style


@dataclass
class OpenTouchClip:
    demo_id: str                      # used verbatim as the group name, e.g. "demo_07" or "demo_007"
    timestamps_ns: np.ndarray         # (T,) int64 device clock
    right_pressure: np.ndarray        # (T,16,16) float32 raw units (inverted: 3072 = no load, 0 = saturated)
    rgb_frames: Iterable[np.ndarray]  # T frames HxWx3 uint8 RGB (JPEG-encoded by the writer)
    left_pressure: np.ndarray | None = None  # optional, as in older internal files
    labels: tuple[int, int] = (0, 0)         # low_light, hand_out_of_frame


OPENTOUCH_LABEL_DTYPE = np.dtype([("low_light", "u1"), ("hand_out_of_frame", "u1")])


def _check_opentouch_clip(clip: OpenTouchClip, where: str) -> int:
    ts = np.asarray(clip.timestamps_ns)
    if ts.ndim != 1 or not np.issubdtype(ts.dtype, np.integer):
        raise ValueError(f"{where}: timestamps_ns must be a 1-D integer array, got {ts.dtype} {ts.shape}")
    t = ts.shape[0]
    for name in ("right_pressure", "left_pressure"):
        arr = getattr(clip, name)
        if arr is None:
            continue
        arr = np.asarray(arr)
        if arr.shape != (t, 16, 16):
            raise ValueError(f"{where}: {name} must have shape ({t},16,16), got {arr.shape}")
    return t


def _opentouch_side_data(t: int, seed: int) -> dict[str, np.ndarray]:
    """Plausible poses/landmarks; landmarks have NaN rows like the release."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (t, 1, 1))
    poses[:, :3, 3] = np.cumsum(rng.normal(0, 0.002, (t, 3)), axis=0)
    wrist = np.array([0.05, -0.25, 0.35]) + np.cumsum(rng.normal(0, 0.001, (t, 3)), axis=0)
    palm = wrist + np.array([0.0, 0.04, 0.05])
    landmarks = palm[:, None, :] + rng.normal(0, 0.03, (t, 21, 3))
    if t:
        # Hand-tracking dropouts: every 5th frame untracked, plus one partial frame.
        landmarks[::5] = np.nan
        landmarks[t // 2, :4] = np.nan
    return {
        "camera_poses": poses.astype(np.float64),
        "right_hand_landmarks": landmarks.astype(np.float64),
        "right_palm_pos": palm.astype(np.float64),
        "right_wrist_pos": wrist.astype(np.float64),
    }


def write_opentouch_scene(path: Path, clips: list[OpenTouchClip], *, swap_rb: bool = True, jpeg_quality: int = 90) -> None:
    """Write one OpenTouch-style scene HDF5 (every key of the release).

    `swap_rb=True` stores the JPEGs with R and B swapped like the release.
    """
    import h5py

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    image_hw: tuple[int, int] | None = None
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        for clip in clips:
            where = f"{path.name}::data/{clip.demo_id}"
            t = _check_opentouch_clip(clip, where)
            g = data.create_group(clip.demo_id)
            for name, arr in _opentouch_side_data(t, _seed_of(where)).items():
                g.create_dataset(name, data=arr)
            labels = np.zeros(1, dtype=OPENTOUCH_LABEL_DTYPE)
            labels[0] = tuple(int(v) for v in clip.labels)
            g.create_dataset("labels", data=labels)
            g.create_dataset("right_pressure", data=np.asarray(clip.right_pressure, dtype=np.float32))
            if clip.left_pressure is not None:
                g.create_dataset("left_pressure", data=np.asarray(clip.left_pressure, dtype=np.float32))
            g.create_dataset("timestamps", data=np.asarray(clip.timestamps_ns, dtype=np.int64))
            jpegs = g.create_dataset("rgb_images_jpeg", shape=(t,), dtype=h5py.vlen_dtype(np.uint8))
            n = 0
            for frame in clip.rgb_frames:
                if n >= t:
                    raise ValueError(f"{where}: more RGB frames than timestamps ({t})")
                buf = _encode_jpeg(frame, jpeg_quality, swap_rb=swap_rb, where=f"{where} frame {n}")
                jpegs[n] = np.frombuffer(buf, dtype=np.uint8)
                image_hw = image_hw or (frame.shape[0], frame.shape[1])
                n += 1
            if n != t:
                raise ValueError(f"{where}: {n} RGB frames for {t} timestamps")
        h, w = image_hw or (1408, 1408)  # Aria RGB full resolution when no frame was given
        cal = f.create_group("calibration/rgb")
        t_dev_cam = np.eye(4)
        t_dev_cam[:3, 3] = [-0.0045, -0.0110, 0.0005]
        cal.create_dataset("T_device_camera", data=t_dev_cam)
        cal.create_dataset("focal_length", data=np.float64(0.43 * w))
        cal.create_dataset("image_size", data=np.array([w, h], dtype=np.int64))
        cal.create_dataset("principal_point", data=np.array([w // 2, h // 2], dtype=np.int64))
        slam = np.eye(4)
        slam[:3, 3] = [0.01, -0.02, 0.0]
        f.create_dataset("transform_slam_to_rgb", data=slam)


OPENTOUCH_ANNOTATION_COLUMNS = ("id", "action", "grip_type", "object_name", "object_category", "environment")


def write_opentouch_annotations(path: Path, rows: list[dict]) -> None:
    """Write the annotation table: column "id" = "<scene>::<demo_id>" plus label columns.

    Tab-separated when the suffix is .tsv, comma-separated otherwise. Extra
    keys in `rows` become extra columns (after the standard ones).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(OPENTOUCH_ANNOTATION_COLUMNS)
    for row in rows:
        if "id" not in row or "::" not in str(row["id"]):
            raise ValueError(f"{path}: annotation row needs id '<scene>::<demo_id>', got {row!r}")
        columns += [k for k in row if k not in columns]
    delimiter = "\t" if path.suffix.lower() == ".tsv" else ","
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=columns, delimiter=delimiter, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow(row)


# --------------------------------------------------------------------------
# TouchAnything-style

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

    _write_json_lines(folder / "jq_pressure.json", _ta_jq_rows(ep, t))
    ts = np.asarray(ep.ts_epoch_s, dtype=np.float64)
    for kind, name in (("wilor", "wilor_hands.json"), ("hamer", "hamer_hands.json"),
                       ("rokoko", "rokoko_hands.json"), ("vive", "vive_poses.json")):
        _write_json_lines(folder / name, _ta_side_rows(kind, ts, _seed_of(f"{folder.name}/{kind}")))

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


# --------------------------------------------------------------------------
# htdata-native (docs/NATIVE_FORMAT.md)

NATIVE_FORMAT = "htdata-native"
NATIVE_FORMAT_VERSION = 1


@dataclass
class NativeHand:
    layout: str                  # a registered layout id, e.g. "opentouch_right_16x16"
    values: np.ndarray           # (M,H,W) float32 raw glove units, H,W = the layout's grid
    timestamps_ns: np.ndarray    # (M,) int64 on the glove's OWN clock, at its own rate
    clock_offset_ns: int = 0     # added to timestamps_ns to bring them onto the video clock


@dataclass
class NativeRecording:
    task: str
    scene: str
    video_frames: Iterable[np.ndarray]   # egocentric RGB uint8 HxWx3, streamed
    video_timestamps_ns: np.ndarray      # (N,) int64 on the video clock, one per frame
    hands: dict[str, NativeHand]         # "left" / "right" -> hand data
    operator: str = ""
    notes: str = ""
    video_storage: str = "mp4"           # "mp4" -> ego.mp4 ; "jpeg" -> frames/000000.jpg ...
    jpeg_quality: int = 90
    extra: dict = field(default_factory=dict)  # free-form, stored under recording.json "extra"

    def validate(self) -> None:
        if self.video_storage not in ("mp4", "jpeg"):
            raise ValueError(f"video_storage must be 'mp4' or 'jpeg', got {self.video_storage!r}")
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

    from htdata.resources import validate_json

    rec.validate()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    video_ts = np.asarray(rec.video_timestamps_ns, dtype=np.int64)
    np.save(folder / "ego_timestamps.npy", video_ts)
    if rec.video_storage == "mp4":
        write_h264(folder / "ego.mp4", rec.video_frames, fps=_median_fps(video_ts))
        video = {"file": "ego.mp4", "timestamps": "ego_timestamps.npy"}
    else:
        frames_dir = folder / "frames"
        frames_dir.mkdir(exist_ok=True)
        for i, frame in enumerate(rec.video_frames):
            _check_rgb_frame(frame, f"{folder} frame {i}")
            ok = cv2.imwrite(str(frames_dir / f"{i:06d}.jpg"), np.ascontiguousarray(frame[..., ::-1]),
                             [cv2.IMWRITE_JPEG_QUALITY, int(rec.jpeg_quality)])
            if not ok:
                raise ValueError(f"{frames_dir}/{i:06d}.jpg: JPEG write failed")
        video = {"frames_dir": "frames", "timestamps": "ego_timestamps.npy"}

    hands = {}
    for hand, h in sorted(rec.hands.items()):
        name = f"tactile_{hand}.npz"
        np.savez(folder / name, values=np.asarray(h.values, dtype=np.float32),
                 timestamps_ns=np.asarray(h.timestamps_ns, dtype=np.int64))
        hands[hand] = {"layout": h.layout, "file": name, "clock_offset_ns": int(h.clock_offset_ns)}

    doc = {
        "format": NATIVE_FORMAT,
        "format_version": NATIVE_FORMAT_VERSION,
        "task": rec.task,
        "scene": rec.scene,
        "operator": rec.operator,
        "notes": rec.notes,
        "video": video,
        "hands": hands,
    }
    if rec.extra:
        doc["extra"] = rec.extra
    validate_json(doc, "recording", where=str(folder / "recording.json"))
    (folder / "recording.json").write_text(json.dumps(doc, indent=1))
