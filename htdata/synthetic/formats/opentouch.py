"""OpenTouch-style writer: one HDF5 per scene (clips under `data/demo_NN`) + annotations.csv."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from htdata.synthetic.formats.media import encode_jpeg, seed_of


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
            for name, arr in _opentouch_side_data(t, seed_of(where)).items():
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
                buf = encode_jpeg(frame, jpeg_quality, swap_rb=swap_rb, where=f"{where} frame {n}")
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
