"""Export one htdata dataset version as a LeRobot v3.0 dataset (`htdata export lerobot`).

Layout written (LeRobot's v3.0 format, codebase_version "v3.0"):

    OUT/meta/info.json                          features (dtype/shape/names), fps, path templates, splits
    OUT/meta/stats.json                         per feature: min/max/mean/std/count/q01/q10/q50/q90/q99
    OUT/meta/tasks.parquet                      task string (pandas index) -> task_index
    OUT/meta/episodes/chunk-000/file-000.parquet one row per episode: length, tasks, data/video file, indices
    OUT/data/chunk-CCC/file-FFF.parquet         one row per frame (episodes appended, files rolled at 100 MB)
    OUT/videos/<key>/chunk-CCC/file-FFF.mp4     one H.264 file per episode and video feature
    OUT/meta/htdata/                            what LeRobot has no place for: layouts, coverage / region /
                                                part masks, the split assignment, episode ids

One LeRobot episode per htdata episode. Frame features:
  observation.images.egocentric       video, the stored 224x224 RGB frame
  observation.tactile.<hand>.raw      float32 (rows*cols,): the raw row paired with the frame, the glove's grid
                                      flattened row-major (info.grid = [rows, cols]; names "r<row>c<col>")
                                      (non-finite cells, i.e. no taxel there, as 0; a hand recorded with two grid
                                      shapes gets one feature per shape, ...raw_<rows>x<cols>)
  observation.tactile.<hand>.map      video (--maps only), the canonical 224x224 map, value x 255 as grey
  observation.present                 bool per source (egocentric, tactile.<hand>...): is the value real?
  htdata.frame_index                  int64, the stored htdata frame (within its episode) of the row
LeRobot needs every feature in every frame, so a frame missing a source is filled and flagged
in observation.present: a missing RGB frame repeats the last real one (black before the first),
a missing glove row is zeros. Unpaired full-rate glove rows (the ones between two frames) are not
exported: LeRobot frames are one row per frame.

Time: LeRobot's loader finds a row's video frame as round(timestamp x fps) and then checks the
frame's time against the row's within 1e-4 s, so rows must sit on an exact 1/fps grid. Each
episode is therefore laid on the grid of its stored source clock (t_rgb_ns from its first frame):
tick k (timestamp k/fps, the video frame's pts) takes the stored frame nearest k/fps on that
clock, for ticks up to the one nearest the last frame. On a regular clock that is every frame
once, in order; jitter under half a period changes nothing; a gap repeats the frames beside it,
a clock running fast skips one. `htdata.frame_index` names the stored frame of every row.
fps = the episodes' rate (they must agree) unless `--fps F` sets another.

Stats are accumulated in the export's single pass (no second read): exact mean/std/min/max,
quantiles exact per episode and frame-weighted across episodes (as LeRobot aggregates
them), exact for video features (per-channel 256-bin histograms).

Read-only on DATASET; memory bounded by one episode's raw rows; atomic: everything is
written under OUT's sibling `.OUT.partial/` and renamed to OUT at the end, so a killed
export never leaves an OUT that looks complete (the next run removes the leftover).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from htdata import storage
from htdata.codec import decode_json, decode_rgb, decode_tactile
from htdata.format import CANVAS, HANDS, JSON_MEMBER, RGB_MEMBER, raw_member, tactile_member
from htdata.lerobot_meta import CHUNKS_SIZE, DATA_FILE_MB, DATA_PATH, VIDEO_PATH, part_of, write_meta
from htdata.lerobot_stats import FeatureStats, VideoStats
from htdata.rawstream import paired_row
from htdata.reader import DatasetReader
from htdata.videoencode import VideoWriter

RGB_KEY = "observation.images.egocentric"
PRESENT_KEY = "observation.present"
SOURCE_KEY = "htdata.frame_index"      # which stored frame a row is: the rows sit on a 1/fps grid
Progress = Callable[[int], None]


def raw_key(hand: str) -> str:
    return f"observation.tactile.{hand}.raw"


def map_key(hand: str) -> str:
    return f"observation.tactile.{hand}.map"


@dataclass
class LeRobotExportConfig:
    dataset: str
    out: Path
    version: int | None = None
    split: str | None = None
    part: str | None = None
    fps: float | None = None          # None: the episodes' own rate, no resampling
    maps: bool = False
    codec: str = "libx264"
    crf: int = 18
    gop: int = 2                      # keyframe every 2 frames: LeRobot's default, cheap random access
    force: bool = False

    def validate(self) -> None:
        if self.part is not None and self.split is None:
            raise ValueError("--part needs --split NAME")
        if self.fps is not None and not (self.fps > 0 and float(self.fps).is_integer()):
            raise ValueError(f"--fps must be a positive whole number (LeRobot's fps is an int), got {self.fps}")
        if not 0 <= self.crf <= 51:
            raise ValueError(f"crf must be in 0..51, got {self.crf}")
        if self.gop < 1:
            raise ValueError(f"gop must be >= 1, got {self.gop}")
        if self.codec not in ("libx264", "libsvtav1"):
            raise ValueError(f"codec must be libx264 or libsvtav1, got {self.codec!r}")
        if storage.is_url(str(self.out)):
            raise ValueError(f"{self.out}: the export writes a local directory")


# --------------------------------------------------------------------------- the export
@dataclass(frozen=True)
class RawSlot:
    """One raw feature: a hand's glove rows of one grid shape (a hand recorded with two grid shapes has two)."""
    hand: str
    grid: tuple[int, int]
    key: str                                  # feature name
    name: str                                 # its entry in observation.present's names


@dataclass
class _Plan:
    positions: list[int]                     # htdata episode positions, in export order
    parts: dict[str, list[str]]              # split part -> episode ids (exported ones), in export order
    hands: list[str]
    slots: list[RawSlot]
    layout_grids: dict[str, tuple[int, int]]  # layout id -> raw grid
    layouts: dict[str, list[str]]            # hand -> layout ids used
    fps: int
    resample: bool
    split_doc: dict | None = None
    video_keys: list[str] = field(default_factory=list)


def plan_export(reader: DatasetReader, cfg: LeRobotExportConfig) -> _Plan:
    """Which episodes, in which order, with which features; errors name the episode."""
    split_doc, parts = None, {}
    if cfg.split is None:
        positions = reader.episode_positions()
    else:
        split_doc = reader.split(cfg.split)
        names = [cfg.part] if cfg.part is not None else list(split_doc["parts"])
        positions = []
        for name in names:
            # each part contiguous in episode order: info.json "splits" can then say "start:end"
            pos = reader.episode_positions(cfg.split, name)
            parts[name] = [reader.episodes[p]["episode_id"] for p in pos]
            positions += pos
    if not positions:
        raise ValueError(f"{reader.root}: nothing to export (no episodes selected)")
    hands = [h for h in HANDS if any(h in reader.episodes[p]["hands"] for p in positions)]
    layout_grids: dict[str, tuple[int, int]] = {}
    layouts: dict[str, list[str]] = {}
    for p in positions:
        ep = reader.episodes[p]
        for hand, layout_id in sorted(ep["layouts"].items()):
            if layout_id not in layout_grids:
                grid = reader.layout(layout_id).get("grid")
                if not grid or len(grid) != 2:
                    raise ValueError(f"episode {ep['episode_id']!r}: layout {layout_id!r} names no raw grid")
                layout_grids[layout_id] = (int(grid[0]), int(grid[1]))
            if layout_id not in layouts.setdefault(hand, []):
                layouts[hand].append(layout_id)
    slots = []
    for hand in hands:
        grids = list(dict.fromkeys(layout_grids[lid] for lid in layouts.get(hand, [])))
        for g in grids:
            # one feature has one shape: a hand seen with two grid shapes gets a feature per shape
            key = raw_key(hand) if len(grids) == 1 else f"{raw_key(hand)}_{g[0]}x{g[1]}"
            slots.append(RawSlot(hand, g, key, key.removeprefix("observation.")))
    if int(reader.manifest.get("format_version", 0)) < 3:
        raise ValueError(f"{reader.root}: format {reader.manifest.get('format_version')} stores no raw glove rows; "
                         f"the export needs format 3 (re-ingest the sources)")
    if cfg.fps is not None:
        fps, resample = int(cfg.fps), True
    else:
        rates = {}
        for p in positions:
            ep = reader.episodes[p]
            rates.setdefault(int(round(float(ep.get("fps") or 0))), ep["episode_id"])
        if len(rates) != 1 or 0 in rates:
            raise ValueError(f"episodes have frame rates {sorted(rates)} (e.g. {sorted(rates.items())[:3]}); "
                             f"LeRobot has one fps per dataset: pass --fps F to resample")
        fps, resample = next(iter(rates)), False
    video_keys = [RGB_KEY] + ([map_key(h) for h in hands] if cfg.maps else [])
    return _Plan(positions, parts, hands, slots, layout_grids, layouts, fps, resample, split_doc, video_keys)


def features(plan: _Plan) -> dict:
    video_info = {"video.height": CANVAS, "video.width": CANVAS, "video.codec": "h264", "video.pix_fmt": "yuv420p",
                  "video.is_depth_map": False, "video.fps": plan.fps, "video.channels": 3, "has_audio": False}
    feats: dict = {}
    for key in plan.video_keys:
        feats[key] = {"dtype": "video", "shape": [CANVAS, CANVAS, 3], "names": ["height", "width", "channels"],
                      "info": dict(video_info)}
    for slot in plan.slots:
        rows, cols = slot.grid
        # flat (rows*cols,), row-major, the grid in "info": LeRobot's tooling and policies take state
        # features as 1-D vectors (lerobot-doctor 0.2.0 crashes on a 2-D one); reshape(rows, cols) restores it
        feats[slot.key] = {"dtype": "float32", "shape": [rows * cols],
                           "names": [f"r{r}c{c}" for r in range(rows) for c in range(cols)],
                           "info": {"grid": [rows, cols], "order": "row-major", "units": "raw glove units"}}
    feats[PRESENT_KEY] = {"dtype": "bool", "shape": [1 + len(plan.slots)],
                          "names": ["egocentric", *[slot.name for slot in plan.slots]]}
    feats[SOURCE_KEY] = {"dtype": "int64", "shape": [1], "names": None,
                         "info": {"what": "the htdata frame (within its episode) this row was taken from"}}
    for name, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                        ("index", "int64"), ("task_index", "int64")):
        feats[name] = {"dtype": dtype, "shape": [1], "names": None}
    return feats


def _episode_schedule(reader: DatasetReader, pos: int, plan: _Plan) -> tuple[list[int], list[float]]:
    """(global sample index per exported frame, timestamp in s per exported frame) of one episode."""
    first, n = reader.episode_range(pos)
    eid = reader.episodes[pos]["episode_id"]
    times = []
    for i in range(first, first + n):
        meta = decode_json(reader.sample(i, (JSON_MEMBER,))[JSON_MEMBER], f"{reader.root}: {reader.key(i)}")
        if meta.get("t_rgb_ns") is None:
            raise ValueError(f"{reader.root}: {reader.key(i)}: sample has no t_rgb_ns time")
        times.append(int(meta["t_rgb_ns"]))
    t = (np.asarray(times, np.int64) - times[0]) / 1e9
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ValueError(f"episode {eid!r} frame {k}: time does not increase ({t[k - 1]:.6f} s -> {t[k]:.6f} s)")
    ticks = np.arange(_ticks(t[-1], plan.fps)) / plan.fps
    right = np.clip(np.searchsorted(t, ticks), 0, n - 1)
    left = np.clip(right - 1, 0, n - 1)
    nearest = np.where(np.abs(t[left] - ticks) <= np.abs(t[right] - ticks), left, right)
    return [first + int(k) for k in nearest], ticks.tolist()


def _ticks(duration_s: float, fps: int) -> int:
    """Rows of an episode whose last frame is `duration_s` after its first: 1/fps ticks, the last one nearest it."""
    return int(round(duration_s * fps)) + 1


def _frames_out(reader: DatasetReader, pos: int, plan: _Plan) -> int:
    """Rows episode `pos` will have (two JSON reads)."""
    first, n = reader.episode_range(pos)
    t = [decode_json(reader.sample(i, (JSON_MEMBER,))[JSON_MEMBER])["t_rgb_ns"] for i in (first, first + n - 1)]
    return _ticks((t[1] - t[0]) / 1e9, plan.fps)


def _chunk_file(n: int) -> tuple[int, int]:
    return n // CHUNKS_SIZE, n % CHUNKS_SIZE


def export_lerobot(cfg: LeRobotExportConfig, progress: Progress | None = None,
                   on_total: Callable[[int], None] | None = None) -> dict:
    """Write the export (see the module docstring); returns a summary dict."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cfg.validate()
    out = Path(cfg.out)
    if out.exists() and not cfg.force:
        raise FileExistsError(f"{out} exists (pass --force to replace it)")
    if Path(cfg.dataset).resolve() == out.resolve() or Path(cfg.dataset).resolve() in out.resolve().parents:
        raise ValueError(f"{out}: the export may not be written inside DATASET (it is read-only)")
    work = out.parent / f".{out.name}.partial"
    if work.exists():
        shutil.rmtree(work)            # the leftover of a killed export
    work.mkdir(parents=True)
    try:
        with DatasetReader(cfg.dataset, version=cfg.version) as reader:
            plan = plan_export(reader, cfg)
            summary = _write(reader, plan, cfg, work, pa, pq, progress, on_total)
        if out.exists():
            shutil.rmtree(out)
        os.replace(work, out)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    summary["out"] = str(out)
    return summary


def _write(reader, plan: _Plan, cfg: LeRobotExportConfig, work: Path, pa, pq, progress, on_total) -> dict:
    feats = features(plan)
    schema = pa.schema(
        [pa.field(slot.key, pa.list_(pa.float32())) for slot in plan.slots]
        + [pa.field(PRESENT_KEY, pa.list_(pa.bool_())), pa.field("timestamp", pa.float32()),
           pa.field("frame_index", pa.int64()), pa.field("episode_index", pa.int64()),
           pa.field("index", pa.int64()), pa.field("task_index", pa.int64()), pa.field(SOURCE_KEY, pa.int64())])
    stats = {k: FeatureStats() for k in feats if feats[k]["dtype"] != "video"}
    vstats = {k: VideoStats() for k in plan.video_keys}
    tasks: dict[str, int] = {}
    episode_rows: list[dict] = []
    data_file, data_writer, data_bytes = 0, None, 0
    index = 0
    if on_total is not None:   # frames to write, for the progress bar (two JSON reads an episode when resampling)
        on_total(sum(_frames_out(reader, p, plan) for p in plan.positions))
    try:
        for ep_index, pos in enumerate(plan.positions):
            ep = reader.episodes[pos]
            samples, times = _episode_schedule(reader, pos, plan)
            task_index = tasks.setdefault(ep["task"], len(tasks))
            raw, present = _episode_frames(reader, plan, cfg, pos, samples, times, work, ep_index, vstats, progress)
            n = len(samples)
            cols = {PRESENT_KEY: present, "timestamp": np.asarray(times, np.float32),
                    "frame_index": np.arange(n), "episode_index": np.full(n, ep_index),
                    "index": np.arange(index, index + n), "task_index": np.full(n, task_index),
                    SOURCE_KEY: np.asarray(samples) - reader.episode_range(pos)[0]}
            _add_stats(stats, plan, raw, cols)
            table = pa.table({slot.key: pa.array(raw[k].reshape(n, -1).tolist(), schema.field(slot.key).type)
                              for k, slot in enumerate(plan.slots)} | {
                PRESENT_KEY: pa.array(present.tolist(), pa.list_(pa.bool_())),
                "timestamp": pa.array(cols["timestamp"], pa.float32()),
                **{k: pa.array(cols[k], pa.int64())
                   for k in ("frame_index", "episode_index", "index", "task_index", SOURCE_KEY)}},
                schema=schema)
            if data_writer is not None and data_bytes >= DATA_FILE_MB * 1024 * 1024:
                data_writer.close()
                data_writer, data_file = None, data_file + 1
            if data_writer is None:
                path = work / DATA_PATH.format(chunk_index=_chunk_file(data_file)[0],
                                               file_index=_chunk_file(data_file)[1])
                path.parent.mkdir(parents=True, exist_ok=True)
                data_writer, data_bytes = pq.ParquetWriter(str(path), schema), 0
            data_writer.write_table(table)
            data_bytes += table.nbytes
            episode_rows.append(_episode_row(plan, ep, ep_index, index, n, times, data_file))
            index += n
    finally:
        if data_writer is not None:
            data_writer.close()
    write_meta(reader, plan, cfg, work, feats, stats, vstats, tasks, episode_rows, index, pa, pq)
    return {"episodes": len(plan.positions), "frames": index, "fps": plan.fps, "resampled": plan.resample,
            "tasks": len(tasks), "hands": plan.hands, "raw_features": [s.key for s in plan.slots],
            "video_keys": plan.video_keys, "bytes": sum(p.stat().st_size for p in work.rglob("*") if p.is_file())}


def _episode_frames(reader, plan: _Plan, cfg: LeRobotExportConfig, pos: int, samples: list[int], times: list[float],
                    work: Path, ep_index: int, vstats: dict, progress) -> tuple[list[np.ndarray], np.ndarray]:
    """Encode one episode's videos; return its raw rows per slot and the presence flags (see the module doc)."""
    ep = reader.episodes[pos]
    eid = ep["episode_id"]
    wanted = (JSON_MEMBER, RGB_MEMBER, *[raw_member(h) for h in plan.hands],
              *([tactile_member(h) for h in plan.hands] if cfg.maps else []))
    chunk, file = _chunk_file(ep_index)
    videos = {k: VideoWriter(work / VIDEO_PATH.format(video_key=k, chunk_index=chunk, file_index=file),
                             plan.fps, cfg.codec, cfg.crf, cfg.gop) for k in plan.video_keys}
    raw = [np.zeros((len(samples), *slot.grid), np.float32) for slot in plan.slots]
    present = np.zeros((len(samples), 1 + len(plan.slots)), bool)
    slot_of = {h: next(k for k, s in enumerate(plan.slots) if s.hand == h and s.grid == plan.layout_grids[lid])
               for h, lid in ep["layouts"].items()}
    last_rgb = np.zeros((CANVAS, CANVAS, 3), np.uint8)
    cache: tuple[int, dict] | None = None            # a resampled episode may repeat a sample
    first = reader.episode_range(pos)[0]
    for f, (i, t) in enumerate(zip(samples, times)):
        if cache is None or cache[0] != i:
            cache = (i, reader.read_sample(i, wanted)[2])
        members = cache[1]
        where = f"{reader.root}: {reader.key(i)} (episode {eid!r} frame {i - first})"
        if RGB_MEMBER in members:
            last_rgb = decode_rgb(members[RGB_MEMBER], f"{where}.{RGB_MEMBER}")
            present[f, 0] = True
            vstats[RGB_KEY].add(last_rgb)
        videos[RGB_KEY].add(last_rgb, t, where)
        for hand, k in slot_of.items():
            if raw_member(hand) in members:
                row = paired_row(members, hand, where)
                if row.shape != plan.slots[k].grid:
                    raise ValueError(f"{where}: {hand} raw row shaped {row.shape}, "
                                     f"expected {plan.slots[k].grid} (its layout's grid)")
                # NaN / Inf mark cells without a taxel in some sources: 0 (LeRobot stats and
                # normalisation would turn one NaN into NaN everywhere); finite values stay exact
                raw[k][f] = np.where(np.isfinite(row), row, 0.0)
                present[f, 1 + k] = True
        if cfg.maps:
            for hand in plan.hands:
                _add_map_frame(members, hand, t, where, videos[map_key(hand)], vstats[map_key(hand)])
        if progress is not None:
            progress(1)
    for v in videos.values():
        v.close()
    return raw, present


def _add_map_frame(members: dict, hand: str, t: float, where: str, video: VideoWriter, vstats: VideoStats) -> None:
    """--maps: the canonical map as grey (value x 255); black where the hand has no map this frame."""
    grey = np.zeros((CANVAS, CANVAS), np.uint8)
    if tactile_member(hand) in members:
        m = decode_tactile(members[tactile_member(hand)], f"{where}.{tactile_member(hand)}")
        grey = np.round(np.clip(np.nan_to_num(m), 0.0, 1.0) * 255).astype(np.uint8)
    rgb = np.repeat(grey[..., None], 3, axis=2)
    video.add(rgb, t, where)
    if tactile_member(hand) in members:
        vstats.add(rgb)


def _add_stats(stats: dict, plan: _Plan, raw: list[np.ndarray], cols: dict) -> None:
    """One episode into the running stats: raw features over real rows only (absent ones are fill)."""
    present = cols[PRESENT_KEY]
    values = {slot.key: raw[k][present[:, 1 + k]] for k, slot in enumerate(plan.slots)} | cols
    for key, v in values.items():
        if len(v):
            stats[key].add_episode(v.reshape(len(v), -1))


def _episode_row(plan: _Plan, ep: dict, ep_index: int, index: int, n: int, times: list[float], data_file: int) -> dict:
    """The episode's row in meta/episodes (LeRobot's columns, then htdata's)."""
    eid = ep["episode_id"]
    chunk, file = _chunk_file(ep_index)
    d_chunk, d_file = _chunk_file(data_file)
    row = {"episode_index": ep_index, "tasks": [ep["task"]], "length": n,
           "data/chunk_index": d_chunk, "data/file_index": d_file,
           "dataset_from_index": index, "dataset_to_index": index + n,
           "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
           "htdata/episode_id": eid, "htdata/part": part_of(plan, eid),
           **{f"htdata/layout/{h}": ep["layouts"].get(h) for h in plan.hands}}
    for k in plan.video_keys:
        row.update({f"videos/{k}/chunk_index": chunk, f"videos/{k}/file_index": file,
                    f"videos/{k}/from_timestamp": 0.0,
                    f"videos/{k}/to_timestamp": float(times[-1]) + 1.0 / plan.fps})
    return row
