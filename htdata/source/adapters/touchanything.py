"""TouchAnything-style source: one folder per episode, {Scene}/{task}/{trajectory}/.

Facts encoded here (from the release): `pressure_grids.npz` holds
`left_pressure_grid` / `right_pressure_grid` (T,21,21), NaN = no sensor,
the right grid stored with mirrored columns (passed through raw: the
right layout describes the mirroring); scalar keys vary and are never
required. `jq_pressure.json` (JSON Lines) stamps each row with `ts` (epoch
seconds) and `frame_index`. `chest.mp4` is H.264 640x480 at 30 fps and may
differ from the npz by a frame or two. `split.json` at the root lists
episode paths per split (matched on the last three path parts).

Clocks: the tactile clock is `ts` from jq_pressure.json (as int64 ns), or
frame_index / 30 s when that file is absent (noted). Video frames get
their container presentation times, shifted so frame 0 coincides with the
first tactile timestamp. Streams of different lengths are aligned on the
shortest and the difference is noted.

Tactile rows are read from the npz member row by row (`NpzRows`), never
loading the whole array; NaN cells are kept (the rasteriser reads live
cells only).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from htdata.errors import ConfigError, EpisodeError
from htdata.source.adapters.base import EpisodeRef, EpisodeStreams, FileDiscovery
from htdata.source.adapters.discovery import fingerprint_files, sanitise_id
from htdata.source.adapters.npzrows import NpzRowError, NpzRows
from htdata.source.adapters.params import AdapterParam, param_values
from htdata.source.adapters.sourcetree import walk_source
from htdata.source.adapters.streamchecks import check_tactile_shape, file_frame_mismatch_note, iter_episode_video
from htdata.source.adapters.video import VideoError, probe_video_pts_ns

SOURCE = "touchanything"
GRID = (21, 21)
FPS = 30
NPZ_NAME = "pressure_grids.npz"
VIDEO_NAMES = {"chest": "chest.mp4", "left": "left.mp4", "right": "right.mp4"}
JQ_NAME = "jq_pressure.json"
GRID_KEYS = {"left": "left_pressure_grid", "right": "right_pressure_grid"}
DEFAULT_LAYOUTS = {"left": "touchanything_left_21x21", "right": "touchanything_right_21x21"}
SPLIT_FILE = "split.json"
SPLIT_KEYS = ("train", "val", "test_seen", "test_unseen")


def load_split(root: Path) -> dict[tuple[str, ...], str]:
    """(Scene, task, trajectory) -> split name from root/split.json ({} when absent)."""
    path = Path(root) / SPLIT_FILE
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    out: dict[tuple[str, ...], str] = {}
    for name in SPLIT_KEYS:
        for p in doc.get(name, []) or []:
            key = tuple(Path(str(p).strip("/")).parts[-3:])
            if key in out and out[key] != name:
                raise ValueError(f"{path}: {'/'.join(key)} is listed in both {out[key]} and {name}")
            out[key] = name
    return out


def _has_live_value(rows: NpzRows) -> bool:
    """True as soon as any row holds a finite value (early exit: present gloves stop at row 0)."""
    start, size = 0, 1
    while start < rows.num_rows:
        block = rows.read(np.arange(start, min(start + size, rows.num_rows)))
        if np.isfinite(block).any():
            return True
        start, size = start + size, min(size * 2, rows.chunk_rows)
    return False


@dataclass
class TouchAnythingContext:
    """What every episode folder of one source shares."""
    splits: dict[tuple[str, ...], str]
    layouts: dict[str, str]
    video: str


class TouchAnythingAdapter(FileDiscovery):
    name = SOURCE
    recording_files = f"TouchAnything episode folders ({NPZ_NAME})"
    PARAMS: tuple[AdapterParam, ...] = (
        AdapterParam("video", (str,), "chest", f"which camera is the RGB stream: one of {sorted(VIDEO_NAMES)}"),
        AdapterParam("layouts", (dict,), {}, "{hand: layout id} overriding the defaults"),
    )

    def discovery_context(self, root: Path, params: dict) -> TouchAnythingContext:
        params = param_values(self.PARAMS, params)
        video = params["video"]
        if video not in VIDEO_NAMES:
            raise ConfigError(f"touchanything video must be one of {sorted(VIDEO_NAMES)}, got {video!r}")
        return TouchAnythingContext(splits=load_split(Path(root)),
                                    layouts={**DEFAULT_LAYOUTS, **params["layouts"]}, video=video)

    def discovery_files(self, root: Path, params: dict) -> list[Path]:
        return walk_source(root, lambda name: name == NPZ_NAME)

    def discover_file(self, npz: Path, root: Path, params: dict, context: TouchAnythingContext) -> list[EpisodeRef]:
        folder = npz.parent
        parts = folder.relative_to(root).parts
        if len(parts) < 3:
            raise EpisodeError(None, None, "episode folder must be {Scene}/{task}/{trajectory} under the root",
                               file=npz)
        scene, task, traj = parts[-3:]
        episode_id = sanitise_id(f"ta-{scene}-{task}-{traj}")
        hands, n_frames, excluded = self._probe_hands(npz, episode_id)
        if not hands:
            raise EpisodeError(None, None, f"no usable tactile grid ({excluded or 'no grid arrays'})",
                               file=npz, episode_id=episode_id)
        video = context.video
        # exists(), not is_file(): a FIFO or an outside symlink must reach fingerprint_files' check and be refused
        files = [npz] + [folder / n for n in (VIDEO_NAMES[video], JQ_NAME) if os.path.lexists(folder / n)]
        extra: dict = {"video": video}
        read = list(files)
        if (scene, task, traj) in context.splits:
            extra["source_split"] = context.splits[(scene, task, traj)]
            read.append(Path(root) / SPLIT_FILE)   # it decided the record's source_split: hashed with the episode
        if excluded:
            extra["hands_excluded"] = excluded
        return [EpisodeRef(
            episode_id=episode_id, source=SOURCE, source_ref=str(folder), task=task, scene=scene,
            hands=hands, layouts={h: context.layouts[h] for h in hands}, est_frames=n_frames,
            fingerprint=fingerprint_files(root, files), extra=extra, source_files=tuple(sorted(map(str, read))),
        )]

    @staticmethod
    def _probe_hands(npz: Path, episode_id: str) -> tuple[tuple[str, ...], int, dict[str, str]]:
        hands, frames, excluded = [], [], {}
        for hand in ("left", "right"):
            try:
                rows = NpzRows(npz, GRID_KEYS[hand])
            except NpzRowError as exc:
                if "has no array" in str(exc):
                    excluded[hand] = f"no {GRID_KEYS[hand]} array in {NPZ_NAME}"
                    continue
                raise EpisodeError(None, exc.row, str(exc), file=npz, episode_id=episode_id) from exc
            try:
                if rows.num_rows == 0:
                    excluded[hand] = "zero rows"
                elif not _has_live_value(rows):
                    excluded[hand] = "all-NaN"
                else:
                    hands.append(hand)
                    frames.append(rows.num_rows)
            except NpzRowError as exc:
                raise EpisodeError(None, exc.row, str(exc), file=npz, episode_id=episode_id) from exc
            finally:
                rows.close()
        return tuple(hands), min(frames, default=0), excluded

    def open(self, ref: EpisodeRef, params: dict) -> "TouchAnythingStreams":
        return TouchAnythingStreams(ref, params)


def read_jq_timestamps(path: Path, ref: EpisodeRef) -> tuple[np.ndarray, np.ndarray]:
    """(ts_ns int64, frame_index int64) per jq_pressure.json row, in file order."""
    ts, idx = [], []
    with open(path, encoding="utf-8") as f:
        for line_no, line in enumerate(f):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                ts.append(float(row["ts"]))
                idx.append(int(row["frame_index"]))
            except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
                raise EpisodeError(ref, line_no, f"bad jq_pressure.json line {line_no + 1}: {exc}", file=path) from exc
    ts_s = np.asarray(ts, dtype=np.float64)
    if not np.isfinite(ts_s).all():
        bad = int(np.flatnonzero(~np.isfinite(ts_s))[0])
        raise EpisodeError(ref, bad, "non-finite ts in jq_pressure.json", file=path)
    # Split seconds before scaling: float64 epoch seconds keep ~0.2 us, ns product would round worse.
    whole = np.floor(ts_s)
    ns = whole.astype(np.int64) * 1_000_000_000 + np.round((ts_s - whole) * 1e9).astype(np.int64)
    return ns, np.asarray(idx, dtype=np.int64)


class TouchAnythingStreams(EpisodeStreams):
    def __init__(self, ref: EpisodeRef, params: dict):
        super().__init__(ref)
        self.folder = Path(ref.source_ref)
        self.npz = self.folder / NPZ_NAME
        self.video = self.folder / VIDEO_NAMES[ref.extra.get("video", param_values(TouchAnythingAdapter.PARAMS, params)["video"])]
        self._rows: dict[str, NpzRows] = {}
        self._setup_or_close(self._setup)

    def _setup(self) -> None:
        ref = self.ref
        for hand, why in sorted(ref.extra.get("hands_excluded", {}).items()):
            self.notes.append(f"{hand} hand not ingested: {why}")
        self._check_file(self.npz)
        self._check_file(self.video)
        for hand in ref.hands:
            try:
                self._rows[hand] = NpzRows(self.npz, GRID_KEYS[hand])
            except NpzRowError as exc:
                raise EpisodeError(ref, exc.row, str(exc), file=self.npz) from exc
            check_tactile_shape(ref, hand, self._rows[hand].shape, self.npz)
        n_rows = min(r.num_rows for r in self._rows.values())
        if n_rows == 0:
            raise EpisodeError(ref, None, "tactile grids have zero frames", file=self.npz)

        tactile_ts, row_of = self._tactile_clock(n_rows)
        try:
            video_pts = probe_video_pts_ns(self.video)
        except VideoError as exc:
            raise EpisodeError(ref, exc.frame, str(exc), file=self.video) from exc
        if video_pts.size == 0:
            raise EpisodeError(ref, None, "video has zero frames", file=self.video)
        note = file_frame_mismatch_note(self.video.name, video_pts.size, "tactile", tactile_ts.size)
        if note:
            self.notes.append(note)
        n = min(video_pts.size, tactile_ts.size)
        self._n_rgb = n
        self._row_of = row_of[:n]
        self.rgb_timestamps_ns = (video_pts[:n] + tactile_ts[0]).astype(np.int64)
        self.tactile_timestamps_ns = {h: tactile_ts[:n].copy() for h in self._rows}

    def _tactile_clock(self, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
        """Tactile timestamps and, for each, the npz row it stamps."""
        jq = self.folder / JQ_NAME
        if not os.path.lexists(jq):
            self.notes.append(f"{JQ_NAME} absent: tactile clock = frame_index / {FPS} s")
            rows = np.arange(n_rows, dtype=np.int64)
            return rows * 1_000_000_000 // FPS, rows
        ts, idx = read_jq_timestamps(self._check_file(jq), self.ref)
        keep = (idx >= 0) & (idx < n_rows)
        if (~keep).any():
            self.notes.append(f"{JQ_NAME}: {int((~keep).sum())} rows point past the {n_rows} npz rows: ignored")
        ts, idx = ts[keep], idx[keep]
        if ts.size == 0:
            raise EpisodeError(self.ref, None, f"{JQ_NAME} stamps no npz row", file=jq)
        if ts.size < n_rows:
            self.notes.append(f"{JQ_NAME} stamps {ts.size} of {n_rows} npz rows: unstamped rows unused")
        return ts, idx

    def iter_rgb(self) -> Iterator[tuple[int, np.ndarray]]:
        yield from iter_episode_video(self.ref, self.video, self._n_rgb)

    def read_tactile(self, hand: str, indices: np.ndarray) -> np.ndarray:
        self._check_hand(hand)
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self._row_of.size):
            raise EpisodeError(self.ref, int(idx.max()), f"tactile index out of range 0..{self._row_of.size - 1}",
                               file=self.npz)
        try:
            return self._rows[hand].read(self._row_of[idx])   # source dtype: stored bit for bit
        except NpzRowError as exc:
            raise EpisodeError(self.ref, exc.row, str(exc), file=self.npz) from exc

    def close(self) -> None:
        for rows in self._rows.values():
            rows.close()
        self._rows = {}
