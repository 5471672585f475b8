"""OpenTouch-style source: one HDF5 per scene, clips under `data/demo_NN`.

Facts encoded here (from the release): clip ids differ in zero padding
(`demo_7`, `demo_07`, `demo_007`), one pressure frame per RGB frame, both
stamped by `timestamps` (int64 device-clock ns); `right_pressure` is
(T,16,16) float32 in inverted glove units (3072 = no load); JPEGs may be
stored with R and B swapped; labels live in a separate table keyed
"<scene>::<demo_id>", whose file name, delimiter and id column vary
between releases.

params (declared in `OpenTouchAdapter.PARAMS`, checked by the pipeline loader):
  channel_order     "bgr" (default: JPEGs store R and B swapped, as released)
                    or "rgb" (JPEGs store true colours)
  annotations       path to the label table, any name (relative paths: cwd,
                    then root); delimiter detected (tab, comma, ';', '|')
  id_column         column holding "<scene>::<demo_id>" (default: the column
                    whose values look like that, "id" preferred)
  task_field        annotation column holding the task (default "action")
  allow_unlabelled  true: a missing table gives task "unlabelled" + a warning
                    (default false: a missing table is an error naming the
                    --set option that fixes it)
  layouts           optional {hand: layout id} overriding the defaults
  hands             optional list restricting the hands read (e.g. ["right"])

Task rule: the annotation row "<scene>::<demo_id>" (matched exactly, then
by clip number ignoring zero padding); without annotations, or without a
row / value, the task is "unlabelled" and `extra["task_source"]` says why
(with allow_unlabelled and no table, the episode's notes say so too).

Discovery is per scene file (`FileDiscovery`): a file that does not open,
or holds a clip without right_pressure or whose left hand has no layout,
is one failure (`discover_all`) while the other files are still found;
frame-level problems raise from the opened streams.
"""

from __future__ import annotations

import csv
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from htdata.errors import ConfigError, EpisodeError
from htdata.source.adapters.base import EpisodeRef, EpisodeStreams, FileDiscovery
from htdata.source.adapters.discovery import fingerprint_files, sanitise_id
from htdata.source.adapters.hdf5safe import check_hdf5_size, in_file
from htdata.source.adapters.params import AdapterParam, param_values
from htdata.source.adapters.sourcetree import walk_source
from htdata.source.adapters.streamchecks import check_stream_rows, check_tactile_shape
from htdata.source.rgb import CHANNEL_ORDERS, decode_jpeg_frame, to_rgb

log = logging.getLogger(__name__)

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


ANNOTATION_DELIMITERS = ("\t", ",", ";", "|")
# "<scene>::<demo>" as the release keys its label rows
_ID_VALUE_RE = re.compile(r"^[^:]+::[^:]+$")
FIX_TABLE = "--set adapter.params.annotations=PATH"
FIX_UNLABELLED = "--set adapter.params.allow_unlabelled=true"
FIX_ID_COLUMN = "--set adapter.params.id_column=COLUMN"


def sniff_delimiter(lines: list[str], suffix: str) -> str:
    """The delimiter of a label table: tab for .tsv, else the candidate splitting the header most and consistently."""
    if suffix.lower() == ".tsv":
        return "\t"
    head = [ln for ln in lines if ln.strip()][:6]
    if not head:
        return ","

    def score(d: str) -> tuple[int, int]:
        counts = [ln.count(d) for ln in head]
        return (sum(c == counts[0] for c in counts) if counts[0] else 0, counts[0])

    return max(ANNOTATION_DELIMITERS, key=score)


def detect_id_column(fields: list[str], rows: list[dict], path: Path) -> str:
    """The column whose values look like `<scene>::<demo>` ("id" preferred when several do)."""
    def looks_like_ids(col: str) -> bool:
        values = [(r.get(col) or "").strip() for r in rows]
        values = [v for v in values if v]
        return bool(values) and sum(bool(_ID_VALUE_RE.match(v)) for v in values) >= 0.9 * len(values)

    found = [c for c in fields if looks_like_ids(c)]
    if len(found) == 1:
        return found[0]
    if "id" in found:
        return "id"
    if not found:
        raise ConfigError(f"{path}: no column of the annotation table holds ids like '<scene>::<demo_id>' "
                          f"(columns: {fields}); name it with {FIX_ID_COLUMN}")
    raise ConfigError(f"{path}: several columns hold '<scene>::<demo_id>' ids ({found}); choose one with "
                      f"{FIX_ID_COLUMN}")


def load_annotations(path: Path, task_field: str, id_column: str | None = None) -> dict[str, str]:
    """Map "<scene>::<demo_id>" -> task from a label table.

    Any file name; delimiter detected (`sniff_delimiter`); the id column is
    `id_column` or detected (`detect_id_column`).
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: annotation file not found")
    text = path.read_text(encoding="utf-8-sig")
    lines = text.splitlines()
    reader = csv.DictReader(lines, delimiter=sniff_delimiter(lines, path.suffix))
    fields = [f.strip() for f in (reader.fieldnames or [])]
    reader.fieldnames = fields
    rows = list(reader)
    if id_column is None:
        id_column = detect_id_column(fields, rows, path)
    for col, fix in ((id_column, FIX_ID_COLUMN), (task_field, "--set adapter.params.task_field=COLUMN")):
        if col not in fields:
            raise ConfigError(f"{path}: annotation table has no column {col!r} (columns: {fields}); "
                              f"name the right one with {fix}")
    tasks: dict[str, str] = {}
    line_of: dict[str, int] = {}
    for lineno, row in enumerate(rows, 2):   # line 1 is the header
        key = (row.get(id_column) or "").strip()
        if key:
            task = (row.get(task_field) or "").strip()
            if key in tasks and tasks[key] != task:   # which one is right only the table's author knows
                raise ConfigError(f"{path}: id {key!r} is labelled twice with different tasks: line "
                                  f"{line_of[key]} says {tasks[key]!r}, line {lineno} says {task!r}; keep one row")
            tasks[key] = task
            line_of.setdefault(key, lineno)
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
    missing_table: Path | None = None   # annotations given but absent, allowed by allow_unlabelled
    table: Path | None = None           # the annotation table read: it decides tasks, so it is a source file


class OpenTouchAdapter(FileDiscovery):
    name = SOURCE
    recording_files = "OpenTouch HDF5 scene files (*.hdf5)"
    PARAMS: tuple[AdapterParam, ...] = (
        AdapterParam("channel_order", (str,), "bgr", f"JPEG channel order, one of {CHANNEL_ORDERS}"),
        AdapterParam("annotations", (str,), None, "label table path (cwd, then the source root)"),
        AdapterParam("id_column", (str,), None, "label column holding '<scene>::<demo_id>' (default: detected)"),
        AdapterParam("task_field", (str,), "action", "label column holding the task"),
        AdapterParam("allow_unlabelled", (bool,), False, "a missing label table gives task 'unlabelled'"),
        AdapterParam("layouts", (dict,), {}, "{hand: layout id or JSON path} overriding the defaults"),
        AdapterParam("hands", (list,), ["left", "right"], "hands read (e.g. ['right'])"),
    )

    def discovery_context(self, root: Path, params: dict) -> OpenTouchContext:
        params = param_values(self.PARAMS, params)
        task_field = params["task_field"]
        tasks, missing = None, None
        if params["annotations"]:
            path = _resolve(str(params["annotations"]), Path(root))
            if path.is_file():
                tasks = load_annotations(path, task_field, params["id_column"])
            elif params["allow_unlabelled"]:
                missing = path
                log.warning("opentouch: annotation table %s not found: every clip gets task %r "
                            "(allow_unlabelled)", path, FALLBACK_TASK)
            else:
                raise FileNotFoundError(
                    f"annotation table {params['annotations']!r} not found (looked in {Path.cwd()} and {root}); "
                    f"point to it with {FIX_TABLE}, or ingest without labels with {FIX_UNLABELLED}")
        return OpenTouchContext(tasks=tasks, by_number=_annotation_lookup(tasks or {}),
                                layouts={**DEFAULT_LAYOUTS, **params["layouts"]},
                                allowed_hands=tuple(params["hands"]), missing_table=missing,
                                table=path if tasks is not None else None)

    def discovery_files(self, root: Path, params: dict) -> list[Path]:
        return walk_source(root, lambda name: name.endswith(".hdf5"))

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
            if context.missing_table is not None:
                task_source = f"fallback: annotation table {context.missing_table} not found (allow_unlabelled)"
            refs.append(EpisodeRef(
                episode_id=episode_id, source=SOURCE, source_ref=f"{path}::data/{demo_id}", task=task, scene=scene,
                hands=hands, layouts={h: layouts[h] for h in hands}, est_frames=n_frames,
                fingerprint=fingerprint, extra={"task_source": task_source, "demo_id": demo_id},
                source_files=(str(path),) + ((str(context.table),) if context.table is not None else ()),
            ))
        return refs

    @staticmethod
    def _list_clips(f, path: Path) -> list[tuple[str, int, bool]]:
        """(demo id, frames, has a left hand) per clip, links resolved inside the file (hdf5safe.in_file).

        A clip whose links cannot be followed (dangling, a loop, leaving the file) is still listed, with 0
        frames: opening it raises the same one-line EpisodeError naming the link, so it fails alone and
        the file's other clips are ingested.
        """
        try:
            data = in_file(None, f, "data", path)
        except KeyError:
            raise EpisodeError(None, None, "HDF5 has no 'data' group (not an OpenTouch scene file)",
                               file=path) from None
        clips = []
        for demo_id in sorted((k for k in data.keys() if k.startswith("demo_")), key=_clip_sort_key):
            try:
                g = in_file(None, data, demo_id, path)
                right = in_file(None, g, "right_pressure", path)
            except KeyError:
                raise EpisodeError(None, None, f"clip data/{demo_id} has no right_pressure", file=path) from None
            except EpisodeError:     # named again, per episode, when the clip is opened
                clips.append((demo_id, 0, False))
                continue
            clips.append((demo_id, int(right.shape[0]) if right.shape else 0, "left_pressure" in g))
        return clips

    def open(self, ref: EpisodeRef, params: dict) -> "OpenTouchStreams":
        return OpenTouchStreams(ref, params)


class OpenTouchStreams(EpisodeStreams):
    def __init__(self, ref: EpisodeRef, params: dict):
        import h5py

        super().__init__(ref)
        self.channel_order = param_values(OpenTouchAdapter.PARAMS, params)["channel_order"]
        if self.channel_order not in CHANNEL_ORDERS:
            raise ConfigError(f"opentouch channel_order must be one of {CHANNEL_ORDERS}, got {self.channel_order!r}")
        file_text, _, group = ref.source_ref.partition("::")
        self.path = self._check_file(Path(file_text))
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
        try:
            g = in_file(ref, self._file, group, self.path)
        except KeyError:
            raise EpisodeError(ref, None, f"clip {group} not found") from None
        try:
            stamps = in_file(ref, g, "timestamps", self.path)
            check_hdf5_size(ref, stamps, self.path)
            check_stream_rows(ref, "timestamps", int(stamps.shape[0]) if stamps.shape else 1, self.path)
            ts = np.asarray(stamps[()], dtype=np.int64)
            self._jpegs = in_file(ref, g, "rgb_images_jpeg", self.path)
            check_hdf5_size(ref, self._jpegs, self.path)
            self._pressure = {}
            for hand in ref.hands:
                ds = in_file(ref, g, f"{hand}_pressure", self.path)
                check_tactile_shape(ref, hand, ds.shape, self.path)
                check_hdf5_size(ref, ds, self.path)
                self._pressure[hand] = ds
        except KeyError as exc:
            raise EpisodeError(ref, None, f"clip {group} lacks a dataset: {exc}") from exc
        except OSError as exc:
            raise EpisodeError(ref, None, f"HDF5 read failed: {exc}") from exc
        if ref.extra.get("task_source", "").startswith("fallback: annotation table"):
            self.notes.append(f"task {ref.task!r}: {ref.extra['task_source']}")
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
        for i in range(self._n):
            try:
                buf = np.asarray(self._jpegs[i], dtype=np.uint8)
            except OSError as exc:
                raise EpisodeError(self.ref, i, f"HDF5 read failed: {exc}") from exc
            try:
                img = decode_jpeg_frame(buf)   # its header's size checked before decoding
            except ValueError as exc:
                raise EpisodeError(self.ref, i, str(exc)) from exc
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
        return np.asarray(rows)[inverse]   # source dtype: stored bit for bit (raw_<hand>.npy)

    def close(self) -> None:
        f = getattr(self, "_file", None)
        if f is not None:
            f.close()
            self._file = None
