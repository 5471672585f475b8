"""OpenTouch-style source: one HDF5 per scene, clips under `data/demo_NN`.

Facts encoded here (from the release): clip ids differ in zero padding
(`demo_7`, `demo_07`, `demo_007`), one pressure frame per RGB frame, both
stamped by `timestamps` (int64 device-clock ns); `right_pressure` is
(T,16,16) float32 in inverted glove units (3072 = no load); JPEGs may be
stored with R and B swapped; labels live in a separate CSV/TSV keyed
"<scene>::<demo_id>" in column "id".

params:
  channel_order  "bgr" (default: JPEGs store R and B swapped, as released)
                 or "rgb" (JPEGs store true colours)
  annotations    path to the CSV/TSV (relative paths: cwd, then root)
  task_field     annotation column holding the task (default "action")
  layouts        optional {hand: layout id} overriding the defaults
  hands          optional list restricting the hands read (e.g. ["right"])

Task rule: the annotation row "<scene>::<demo_id>" (matched exactly, then
by clip number ignoring zero padding); without annotations, or without a
row / value, the task is "unlabelled" and `extra["task_source"]` says why.

Discovery is per scene file (`FileDiscovery`): a file that does not open,
or holds a clip without right_pressure or whose left hand has no layout,
is one failure (`discover_all`) while the other files are still found;
frame-level problems raise from the opened streams.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from htdata.adapters.base import (
    EpisodeRef, EpisodeStreams, FileDiscovery, check_tactile_shape, fingerprint_files, sanitise_id,
)
from htdata.errors import EpisodeError
from htdata.rgb import CHANNEL_ORDERS, to_rgb

SOURCE = "opentouch"
GRID = (16, 16)
# Only the right-hand glove is described by a shipped layout. The release's left glove
# has no layout file yet (there is no "opentouch_left_16x16"): a clip with left_pressure
# needs params layouts.left (an id or a layout JSON path), or hands = ["right"].
DEFAULT_LAYOUTS = {"right": "opentouch_right_16x16"}
MISSING_LEFT_LAYOUT = "opentouch_left_16x16"
FALLBACK_TASK = "unlabelled"
# cv2 decodes a JPEG to BGR. When the release stored R and B swapped (channel_order "bgr"),
# the decoded array already is the scene in RGB; true-colour JPEGs ("rgb") decode to BGR.
DECODED_ORDER = {"bgr": "rgb", "rgb": "bgr"}
_CLIP_RE = re.compile(r"^demo_(\d+)$")


def clip_number(demo_id: str) -> int | None:
    m = _CLIP_RE.match(demo_id)
    return int(m.group(1)) if m else None


def _resolve(path_text: str, root: Path) -> Path:
    p = Path(path_text)
    if p.is_absolute() or p.exists():
        return p
    return root / p


def load_annotations(path: Path, task_field: str) -> dict[str, str]:
    """Map "<scene>::<demo_id>" -> task from the annotation CSV/TSV (column "id")."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: annotation file not found")
    text = path.read_text(encoding="utf-8-sig")
    first = text.splitlines()[0] if text else ""
    delimiter = "\t" if path.suffix.lower() == ".tsv" or first.count("\t") > first.count(",") else ","
    reader = csv.DictReader(text.splitlines(), delimiter=delimiter)
    fields = reader.fieldnames or []
    for col in ("id", task_field):
        if col not in fields:
            raise ValueError(f"{path}: annotation table has no column {col!r} (columns: {fields})")
    tasks: dict[str, str] = {}
    for row in reader:
        key = (row.get("id") or "").strip()
        if key:
            tasks[key] = (row.get(task_field) or "").strip()
    return tasks


def _annotation_lookup(tasks: dict[str, str]) -> dict[tuple[str, int], str]:
    """(scene, clip number) -> task, to match ids that differ only in zero padding."""
    out = {}
    for key, task in tasks.items():
        scene, _, demo = key.partition("::")
        n = clip_number(demo)
        if n is not None:
            out.setdefault((scene, n), task)
    return out


def _task_for(scene: str, demo_id: str, tasks: dict[str, str] | None, by_number: dict) -> tuple[str, str]:
    if tasks is None:
        return FALLBACK_TASK, "fallback: no annotations given"
    task = tasks.get(f"{scene}::{demo_id}")
    if task is None:
        n = clip_number(demo_id)
        task = by_number.get((scene, n)) if n is not None else None
    if task is None:
        return FALLBACK_TASK, "fallback: clip missing from annotations"
    if not task:
        return FALLBACK_TASK, "fallback: empty task value in annotations"
    return task, "annotations"


def _clip_sort_key(demo_id: str):
    n = clip_number(demo_id)
    return (n if n is not None else float("inf"), demo_id)


@dataclass
class OpenTouchContext:
    """What every scene file of one source shares."""
    tasks: dict[str, str] | None
    by_number: dict
    layouts: dict[str, str]
    allowed_hands: tuple[str, ...]


class OpenTouchAdapter(FileDiscovery):
    name = SOURCE

    def discovery_context(self, root: Path, params: dict) -> OpenTouchContext:
        task_field = params.get("task_field", "action")
        tasks = None
        if params.get("annotations"):
            tasks = load_annotations(_resolve(str(params["annotations"]), Path(root)), task_field)
        return OpenTouchContext(tasks=tasks, by_number=_annotation_lookup(tasks or {}),
                                layouts={**DEFAULT_LAYOUTS, **params.get("layouts", {})},
                                allowed_hands=tuple(params.get("hands", ("left", "right"))))

    def discovery_files(self, root: Path, params: dict) -> list[Path]:
        return sorted(Path(root).rglob("*.hdf5"))

    def discover_file(self, path: Path, root: Path, params: dict, context: OpenTouchContext) -> list[EpisodeRef]:
        import h5py

        scene = path.stem
        fingerprint = fingerprint_files(root, [path])
        try:
            with h5py.File(path, "r") as f:
                clips = self._list_clips(f, path)
        except OSError as exc:
            raise EpisodeError(None, None, f"HDF5 does not open: {exc}", file=path) from exc
        refs = []
        layouts = context.layouts
        for demo_id, n_frames, has_left in clips:
            episode_id = sanitise_id(f"ot-{scene}-{demo_id}")
            hands = tuple(h for h in ("left", "right") if h in context.allowed_hands and (h == "right" or has_left))
            if "left" in hands and "left" not in layouts:
                raise EpisodeError(None, None, f"clip has left_pressure but no left-hand layout is shipped for "
                                   f"OpenTouch ({MISSING_LEFT_LAYOUT!r} does not exist): pass adapter params "
                                   "layouts.left = <layout id or JSON path>, or hands = ['right'] to skip it",
                                   file=path, episode_id=episode_id)
            task, task_source = _task_for(scene, demo_id, context.tasks, context.by_number)
            refs.append(EpisodeRef(
                episode_id=episode_id, source=SOURCE, source_ref=f"{path}::data/{demo_id}", task=task, scene=scene,
                hands=hands, layouts={h: layouts[h] for h in hands}, est_frames=n_frames,
                fingerprint=fingerprint, extra={"task_source": task_source, "demo_id": demo_id},
            ))
        return refs

    @staticmethod
    def _list_clips(f, path: Path) -> list[tuple[str, int, bool]]:
        if "data" not in f:
            raise EpisodeError(None, None, "HDF5 has no 'data' group (not an OpenTouch scene file)", file=path)
        clips = []
        for demo_id in sorted((k for k in f["data"].keys() if k.startswith("demo_")), key=_clip_sort_key):
            g = f["data"][demo_id]
            if "right_pressure" not in g:
                raise EpisodeError(None, None, f"clip data/{demo_id} has no right_pressure", file=path)
            clips.append((demo_id, int(g["right_pressure"].shape[0]), "left_pressure" in g))
        return clips

    def open(self, ref: EpisodeRef, params: dict) -> "OpenTouchStreams":
        return OpenTouchStreams(ref, params)


class OpenTouchStreams(EpisodeStreams):
    def __init__(self, ref: EpisodeRef, params: dict):
        import h5py

        super().__init__(ref)
        self.channel_order = params.get("channel_order", "bgr")
        if self.channel_order not in CHANNEL_ORDERS:
            raise ValueError(f"opentouch channel_order must be one of {CHANNEL_ORDERS}, got {self.channel_order!r}")
        file_text, _, group = ref.source_ref.partition("::")
        self.path = Path(file_text)
        try:
            self._file = h5py.File(self.path, "r")
        except OSError as exc:
            raise EpisodeError(ref, None, f"HDF5 does not open: {exc}") from exc
        try:
            self._setup(group)
        except Exception:
            self.close()
            raise

    def _setup(self, group: str) -> None:
        ref = self.ref
        if group not in self._file:
            raise EpisodeError(ref, None, f"clip {group} not found")
        g = self._file[group]
        try:
            ts = np.asarray(g["timestamps"][()], dtype=np.int64)
            self._jpegs = g["rgb_images_jpeg"]
            self._pressure = {}
            for hand in ref.hands:
                ds = g[f"{hand}_pressure"]
                check_tactile_shape(ref, hand, ds.shape, self.path)
                self._pressure[hand] = ds
        except KeyError as exc:
            raise EpisodeError(ref, None, f"clip {group} lacks a dataset: {exc}") from exc
        except OSError as exc:
            raise EpisodeError(ref, None, f"HDF5 read failed: {exc}") from exc
        lengths = {"timestamps": ts.shape[0], "rgb_images_jpeg": self._jpegs.shape[0],
                   **{f"{h}_pressure": ds.shape[0] for h, ds in self._pressure.items()}}
        n = min(lengths.values())
        if n == 0:
            raise EpisodeError(ref, None, f"clip has zero frames ({lengths})")
        if len(set(lengths.values())) > 1:
            self.notes.append(f"clip lengths differ {lengths}: aligned on shortest ({n})")
        self._n = n
        self.rgb_timestamps_ns = ts[:n].copy()
        self.tactile_timestamps_ns = {h: ts[:n].copy() for h in self._pressure}

    def iter_rgb(self) -> Iterator[tuple[int, np.ndarray]]:
        import cv2

        for i in range(self._n):
            try:
                buf = np.asarray(self._jpegs[i], dtype=np.uint8)
            except OSError as exc:
                raise EpisodeError(self.ref, i, f"HDF5 read failed: {exc}") from exc
            img = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
            if img is None or img.ndim != 3:
                raise EpisodeError(self.ref, i, "JPEG does not decode")
            yield i, np.ascontiguousarray(to_rgb(img, DECODED_ORDER[self.channel_order], where=f"frame {i}"))

    def read_tactile(self, hand: str, indices: np.ndarray) -> np.ndarray:
        self._check_hand(hand)
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            return np.zeros((0, *GRID), dtype=np.float32)
        if idx.min() < 0 or idx.max() >= self._n:
            raise EpisodeError(self.ref, int(idx.max()), f"tactile index out of range 0..{self._n - 1}")
        uniq, inverse = np.unique(idx, return_inverse=True)
        ds = self._pressure[hand]
        try:
            if uniq[-1] - uniq[0] + 1 == uniq.size:  # contiguous: one hyperslab read
                rows = ds[int(uniq[0]):int(uniq[-1]) + 1]
            else:
                rows = ds[uniq.tolist()]
        except OSError as exc:
            raise EpisodeError(self.ref, int(uniq[0]), f"{hand}_pressure read failed: {exc}") from exc
        return np.asarray(rows, dtype=np.float32)[inverse]

    def close(self) -> None:
        f = getattr(self, "_file", None)
        if f is not None:
            f.close()
            self._file = None
