"""htdata-native source: folders holding recording.json (docs/NATIVE_FORMAT.md).

Each hand has its own taxel stream at its own rate on its own clock:
`tactile_<hand>.npz` holds `values` (M,H,W) raw glove units and
`timestamps_ns` (M,) int64; `clock_offset_ns` from recording.json is added
to bring them onto the video clock. The egocentric video is `ego.mp4`
(or a folder of JPEGs) with one int64 ns timestamp per frame in a .npy.
recording.json is validated against schemas/recording.schema.json.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import numpy as np

from htdata.errors import EpisodeError
from htdata.glove.layouts import is_layout_path
from htdata.resources import validate_json
from htdata.source.adapters.base import EpisodeRef, EpisodeStreams, FileDiscovery
from htdata.source.adapters.discovery import fingerprint_files, sanitise_id
from htdata.source.adapters.npzrows import NpzRowError, NpzRows, check_npy_file
from htdata.source.adapters.params import AdapterParam
from htdata.source.adapters.sourcetree import check_source_file, relpath_inside, walk_source
from htdata.source.adapters.streamchecks import check_tactile_shape, file_frame_mismatch_note, iter_episode_video
from htdata.source.adapters.video import VideoError, probe_video_pts_ns
from htdata.source.rgb import decode_jpeg_frame, to_rgb

SOURCE = "native"
RECORDING_JSON = "recording.json"
JPEG_SUFFIXES = (".jpg", ".jpeg")


def load_recording(path: Path, episode_id: str | None = None) -> dict:
    """Read and schema-validate a recording.json; EpisodeError names the file."""

    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise EpisodeError(None, None, f"recording.json does not parse: {exc}", file=path, episode_id=episode_id) from exc
    try:
        validate_json(doc, "recording", where="recording.json")
    except ValueError as exc:
        raise EpisodeError(None, None, f"schema violation: {exc}", file=path, episode_id=episode_id) from exc
    return doc


def _recording_paths(folder: Path, doc: dict, where: Path) -> dict:
    """Absolute paths of every file the recording refers to (no escaping the folder)."""
    try:
        out = {}
        video = doc.get("video")   # absent: a glove-only recording (tactile-only samples)
        if video is not None:
            out["timestamps"] = relpath_inside(folder, video["timestamps"], str(where))
            if "file" in video:
                out["video_file"] = relpath_inside(folder, video["file"], str(where))
            else:
                out["frames_dir"] = relpath_inside(folder, video["frames_dir"], str(where))
        out["hands"] = {h: relpath_inside(folder, spec["file"], str(where)) for h, spec in doc["hands"].items()}
    except ValueError as exc:
        raise EpisodeError(None, None, str(exc), file=where) from exc
    return out


def _recording_layouts(folder: Path, doc: dict, where: Path, episode_id: str) -> dict[str, str]:
    """hand -> layout id, or the absolute path of a layout JSON the recording keeps in its folder."""
    out = {}
    for hand in sorted(doc["hands"]):
        name = doc["hands"][hand]["layout"]
        if is_layout_path(name):
            try:
                path = relpath_inside(folder, name, str(where))
            except ValueError as exc:
                raise EpisodeError(None, None, str(exc), file=where, episode_id=episode_id) from exc
            if not path.is_file():
                raise EpisodeError(None, None, f"{hand} hand layout file {name!r} not found in the recording folder "
                                   f"({path})", file=where, episode_id=episode_id)
            name = str(path)
        out[hand] = name
    return out


def _npz_rows(path: Path) -> int:
    rows = NpzRows(path, "timestamps_ns")
    try:
        return rows.num_rows
    finally:
        rows.close()


def _frame_files(frames_dir: Path) -> list[Path]:
    # one folder's files: by name is the Path order, without comparing Path objects (one file per frame)
    return sorted((p for p in frames_dir.iterdir() if p.suffix.lower() in JPEG_SUFFIXES), key=lambda p: p.name)


# timestamps_ns declaring more rows than this beside the value rows are refused unread (issue 26: a
# 0.84 MB deflated npz declaring 1e8 stamps beside a few hundred rows reached 862 MB before failing)
MAX_STAMP_RATIO = 2
MAX_STAMP_SLACK = 4096


class NativeAdapter(FileDiscovery):
    name = SOURCE
    recording_files = f"native recordings ({RECORDING_JSON})"
    # Everything a native recording needs is in its recording.json: no params.
    PARAMS: tuple[AdapterParam, ...] = ()

    def discovery_files(self, root: Path, params: dict) -> list[Path]:
        return walk_source(root, lambda name: name == RECORDING_JSON)

    def discover_file(self, rec_path: Path, root: Path, params: dict, context) -> list[EpisodeRef]:
        folder = rec_path.parent
        episode_id = sanitise_id(f"nat-{folder.name}")
        doc = load_recording(rec_path, episode_id)
        paths = _recording_paths(folder, doc, rec_path)
        video_files = [paths["timestamps"], paths.get("video_file") or paths["frames_dir"]] if "timestamps" in paths else []
        missing = [p for p in [*paths["hands"].values(), *video_files] if not p.exists()]
        if missing:
            raise EpisodeError(None, None, f"missing files {[str(p) for p in missing]}", file=rec_path,
                               episode_id=episode_id)
        clock_file = paths.get("timestamps") or paths["hands"][sorted(paths["hands"])[0]]
        try:
            check_source_file(clock_file, root)
            est_frames = int(check_npy_file(clock_file)[0][0]) if video_files else _npz_rows(clock_file)
        except (OSError, ValueError, IndexError, NpzRowError) as exc:
            raise EpisodeError(None, None, f"timestamps unreadable: {exc}", file=clock_file,
                               episode_id=episode_id) from exc
        files = [rec_path, *paths["hands"].values()]
        if video_files:
            files += [paths["timestamps"]]
            files += [paths["video_file"]] if "video_file" in paths else _frame_files(paths["frames_dir"])
        hands = tuple(sorted(doc["hands"]))
        layouts = _recording_layouts(folder, doc, rec_path, episode_id)
        # a layout JSON the recording keeps decides its maps: hashed with it (not in the fingerprint, as before)
        read = files + [Path(v) for v in layouts.values() if Path(v).is_absolute()]
        return [EpisodeRef(
            episode_id=episode_id, source=SOURCE, source_ref=str(folder), task=doc["task"], scene=doc["scene"],
            hands=hands, layouts=layouts, est_frames=est_frames,
            fingerprint=fingerprint_files(root, files), source_files=tuple(sorted(set(map(str, read)))),
            extra={"operator": doc.get("operator", ""), "layouts_from": str(rec_path), "clock_offset_ns":
                   {h: int(doc["hands"][h].get("clock_offset_ns", 0)) for h in hands}},
        )]

    def open(self, ref: EpisodeRef, params: dict) -> "NativeStreams":
        return NativeStreams(ref, params)


class NativeStreams(EpisodeStreams):
    def __init__(self, ref: EpisodeRef, params: dict):
        super().__init__(ref)
        self.folder = Path(ref.source_ref)
        self.rec_path = self.folder / RECORDING_JSON
        self._rows: dict[str, NpzRows] = {}
        self._setup_or_close(self._setup)

    def _setup(self) -> None:
        ref = self.ref
        doc = load_recording(self.rec_path, ref.episode_id)
        paths = _recording_paths(self.folder, doc, self.rec_path)
        self._video_file = paths.get("video_file")
        self._frames = _frame_files(paths["frames_dir"]) if "frames_dir" in paths else None
        for hand in ref.hands:
            self._open_hand(hand, paths["hands"][hand], int(doc["hands"][hand].get("clock_offset_ns", 0)))
        if "timestamps" not in paths:   # glove only: the first hand's rows are the samples' clock
            self.has_video = False
            self._n_rgb = 0
            self.rgb_timestamps_ns = self.tactile_timestamps_ns[sorted(ref.hands)[0]].copy()
            self.notes.append(f"no video: tactile-only samples on the {sorted(ref.hands)[0]} glove's clock")
            return

        ts_path = paths["timestamps"]
        try:
            check_npy_file(self._check_file(ts_path))
            video_ts = np.load(ts_path)
        except (OSError, ValueError) as exc:
            raise EpisodeError(ref, None, f"timestamps .npy unreadable: {exc}", file=ts_path) from exc
        if video_ts.ndim != 1 or not np.issubdtype(video_ts.dtype, np.integer):
            raise EpisodeError(ref, None, f"video timestamps must be 1-D int64 ns, got {video_ts.dtype} {video_ts.shape}",
                               file=ts_path)
        n_video = self._count_video_frames()
        note = file_frame_mismatch_note("video", n_video, ts_path.name, video_ts.size)
        if note:
            self.notes.append(note)
        self._n_rgb = min(n_video, video_ts.size)
        if self._n_rgb == 0:
            raise EpisodeError(ref, None, "video has zero frames",
                               file=self._video_file or paths.get("frames_dir"))
        self.rgb_timestamps_ns = video_ts[: self._n_rgb].astype(np.int64)

    def _open_hand(self, hand: str, path: Path, offset_ns: int) -> None:
        ref = self.ref
        self._check_file(path)
        try:
            rows = NpzRows(path, "values")
            self._rows[hand] = rows
            check_tactile_shape(ref, hand, rows.shape, path)   # by its header, before a timestamp is read
            ts_rows = NpzRows(path, "timestamps_ns")
            try:
                declared = ts_rows.num_rows
                if declared > MAX_STAMP_RATIO * rows.num_rows + MAX_STAMP_SLACK:   # by header, before reading
                    raise NpzRowError(None, f"timestamps_ns.npy declares {declared} rows beside {rows.num_rows} "
                                      f"value rows: refused before reading (a stream has one stamp per row)")
                ts = ts_rows.read_all(limit=rows.num_rows)   # stamps past the last value row pair with nothing
            finally:
                ts_rows.close()
        except NpzRowError as exc:
            raise EpisodeError(ref, exc.row, str(exc), file=path) from exc
        if ts.ndim != 1 or not np.issubdtype(ts.dtype, np.integer):
            raise EpisodeError(ref, None, f"timestamps_ns must be 1-D integers, got {ts.dtype} {ts.shape}", file=path)
        n = min(rows.num_rows, ts.size)
        if n == 0:
            raise EpisodeError(ref, None, f"{hand} tactile stream has zero frames", file=path)
        if rows.num_rows != ts.size:
            self.notes.append(f"{path.name}: {rows.num_rows} value rows vs {ts.size} timestamps: aligned on shortest")
        ts = ts[:n].astype(np.int64)
        # Python ints: an offset of 1e308 (or one that pushes a stamp past int64) is named, not an OverflowError
        # or a silent wrap-around of the clock
        first, last = int(ts.min()) + int(offset_ns), int(ts.max()) + int(offset_ns)
        bounds = np.iinfo(np.int64)
        if not (bounds.min <= first and last <= bounds.max):
            raise EpisodeError(ref, None, f"hands.{hand}.clock_offset_ns {offset_ns:.6g} puts the {hand} stamps at "
                               f"{first:.6g}..{last:.6g} ns, outside int64 nanoseconds: a clock offset this large "
                               f"is no offset", file=path.parent / RECORDING_JSON)
        self.tactile_timestamps_ns[hand] = ts + np.int64(offset_ns)

    def _count_video_frames(self) -> int:
        if self._frames is not None:
            return len(self._frames)
        self._check_file(self._video_file)
        try:
            return int(probe_video_pts_ns(self._video_file).size)
        except VideoError as exc:
            raise EpisodeError(self.ref, exc.frame, str(exc), file=self._video_file) from exc

    def iter_rgb(self) -> Iterator[tuple[int, np.ndarray]]:
        if not self.has_video:
            return
        if self._frames is not None:
            yield from self._iter_jpegs()
            return
        yield from iter_episode_video(self.ref, self._video_file, self._n_rgb)

    def _iter_jpegs(self) -> Iterator[tuple[int, np.ndarray]]:
        for i, path in enumerate(self._frames[: self._n_rgb]):
            try:
                img = decode_jpeg_frame(self._check_file(path).read_bytes())   # header's size checked first
            except EpisodeError as exc:       # not a regular file (any more)
                raise exc.at_frame(i) from exc
            except (OSError, ValueError) as exc:
                raise EpisodeError(self.ref, i, str(exc), file=path) from exc
            yield i, np.ascontiguousarray(to_rgb(img, "bgr", where=str(path)))  # cv2 decodes to BGR

    def read_tactile(self, hand: str, indices: np.ndarray) -> np.ndarray:
        self._check_hand(hand)
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        n = self.tactile_timestamps_ns[hand].size
        rows = self._rows[hand]
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise EpisodeError(self.ref, int(idx.max()), f"tactile index out of range 0..{n - 1}", file=rows.path)
        try:
            return rows.read(idx)   # source dtype: stored bit for bit (raw_<hand>.npy)
        except NpzRowError as exc:
            raise EpisodeError(self.ref, exc.row, str(exc), file=rows.path) from exc

    def close(self) -> None:
        for rows in self._rows.values():
            rows.close()
        self._rows = {}
