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
  observation.images.egocentric       video, the stored 224x224 RGB frame (only when some exported frame holds
                                      RGB: a glove-only export has no video feature, not an all-black one)
  observation.tactile.<hand>.raw      float32 (rows*cols,): the raw row paired with the frame, the glove's grid
                                      flattened row-major (info.grid = [rows, cols]; names "r<row>c<col>")
                                      (non-finite cells, i.e. no taxel there, as 0; a hand recorded with two grid
                                      shapes gets one feature per shape, ...raw_<rows>x<cols>)
  observation.tactile.<hand>.map      video (--maps only), the canonical 224x224 map, value x --maps-gain x 255 as grey
  observation.present                 bool per source (egocentric when exported, tactile.<hand>...): real value?
  htdata.frame_index                  int64, the stored htdata frame (within its episode) of the row
  observation.tactile.<hand>.window   (--tactile-window K only) the glove rows recorded since the previous
                                      frame, at the glove's own rate, with ..._mask and ..._dt (lerobot_window.py)
LeRobot needs every feature in every frame, so a frame missing a source is filled and flagged
in observation.present: a missing RGB frame repeats the last real one (black before the first),
a missing glove row is zeros. Without --tactile-window, the unpaired full-rate glove rows (the
ones between two frames) are not exported: `.raw` is the one row paired with the frame.

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
from pathlib import Path
from typing import Callable

import numpy as np

from htdata.errors import DatasetError
from htdata.export.lerobot_meta import CHUNKS_SIZE, DATA_FILE_MB, DATA_PATH, VIDEO_PATH, part_of, write_meta
from htdata.export.lerobot_out import check_out, write_marker
from htdata.export.lerobot_plan import (
    PRESENT_KEY,
    RGB_KEY,
    SOURCE_KEY,
    LeRobotExportConfig,
    _episode_schedule,
    _frames_out,
    _Plan,
    features,
    map_key,
    plan_export,
)
from htdata.export.lerobot_stats import FeatureStats, VideoStats
from htdata.export.lerobot_window import EpisodeWindows, TiledStats, sample_rows, window_features, window_keys
from htdata.export.videoencode import VideoWriter
from htdata.format.canvas import CANVAS
from htdata.format.mapstorage import MapStorage
from htdata.format.table import JSON_MEMBER, RGB_MEMBER, decode_member, raw_member, tactile_member
from htdata.read.rawstream import RawMapRenderer, paired_row
from htdata.read.reader import DatasetReader

Progress = Callable[[int], None]


def _chunk_file(n: int) -> tuple[int, int]:
    return n // CHUNKS_SIZE, n % CHUNKS_SIZE


def export_lerobot(cfg: LeRobotExportConfig, progress: Progress | None = None,
                   on_total: Callable[[int], None] | None = None) -> dict:
    """Write the export (see the module docstring): built in a work folder beside OUT, moved into place at the end.

    Args:
        cfg: what to export and where (dataset, version, split/part, fps, maps, video codec, OUT, --force).
        progress: called with the number of rows just written (1 per row), for a progress bar.
        on_total: called once with the number of rows the export will write, before the first.

    Returns:
        A summary: episodes, frames, fps, resampled, tasks, hands, raw_features, video_keys, bytes, out.

    Raises:
        ValueError: a setting of `cfg` out of range, or an episode the export cannot place on its time grid.
        ExportTargetRefused: an OUT the export may not write or replace (htdata/export/lerobot_out.py).
        FileExistsError: OUT exists and `cfg.force` is not set.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    cfg.validate()
    out = Path(cfg.out)
    check_out(out, Path(cfg.dataset), cfg.force)
    work = out.parent / f".{out.name}.partial"
    if work.is_symlink() or work.is_file():
        raise FileExistsError(f"{work}: the export's work folder is a file or a symlink; remove it by hand")
    if work.exists():
        shutil.rmtree(work)            # the leftover of a killed export
    work.mkdir(parents=True)
    write_marker(work, cfg)
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
    k_window = cfg.tactile_window
    win_feats = window_features(plan.slots, k_window) if k_window else {}
    feats = features(plan) | win_feats
    pa_type = {"float32": pa.list_(pa.float32()), "bool": pa.list_(pa.bool_())}
    schema = pa.schema(
        [pa.field(slot.key, pa.list_(pa.float32())) for slot in plan.slots]
        + [pa.field(key, pa_type[f["dtype"]]) for key, f in win_feats.items()]
        + [pa.field(PRESENT_KEY, pa.list_(pa.bool_())), pa.field("timestamp", pa.float32()),
           pa.field("frame_index", pa.int64()), pa.field("episode_index", pa.int64()),
           pa.field("index", pa.int64()), pa.field("task_index", pa.int64()), pa.field(SOURCE_KEY, pa.int64())])
    stats = {k: FeatureStats() for k in feats if feats[k]["dtype"] != "video"}
    stats.update({window_keys(s.key)[0]: TiledStats(k_window) for s in plan.slots} if k_window else {})
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
            raw, present, windows = _episode_frames(reader, plan, cfg, pos, samples, times, work, ep_index, vstats,
                                                    progress)
            n = len(samples)
            win_cols = {}
            for k, w in windows.items():
                w.add_stats(stats, plan.slots[k].key)
                win_cols |= w.columns(plan.slots[k].key)
            cols = {PRESENT_KEY: present, "timestamp": np.asarray(times, np.float32),
                    "frame_index": np.arange(n), "episode_index": np.full(n, ep_index),
                    "index": np.arange(index, index + n), "task_index": np.full(n, task_index),
                    SOURCE_KEY: np.asarray(samples) - reader.episode_range(pos)[0]}
            _add_stats(stats, plan, raw, cols)
            table = pa.table({slot.key: pa.array(raw[k].reshape(n, -1).tolist(), schema.field(slot.key).type)
                              for k, slot in enumerate(plan.slots)} | {
                key: pa.array(v.tolist(), schema.field(key).type) for key, v in win_cols.items()} | {
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
            "video_keys": plan.video_keys, "bytes": sum(p.stat().st_size for p in work.rglob("*") if p.is_file()),
            "faint_maps": faint_maps({k: v for k, v in vstats.items() if k != RGB_KEY}, plan.maps_gain)}


FAINT_BELOW = 128        # a map video whose p99.9 lit grey level is below this uses less than half its range


def faint_maps(vstats: dict[str, VideoStats], gain: float) -> dict[str, dict]:
    """Map videos that look faint: {key: {"p99_9": grey level of the lit pixels' p99.9, "gain": a --maps-gain
    that brings it near white}} (the same rule as `htdata stats`' scale suggestion, htdata/inspect/scalehint.py)."""
    out = {}
    for key, vs in vstats.items():
        lit = vs.hist[0, 1:]
        if lit.sum() == 0:
            continue
        level = 1 + int(np.searchsorted(np.cumsum(lit) / lit.sum(), 0.999))
        if level < FAINT_BELOW:
            suggested = gain * 255.0 / level
            out[key] = {"p99_9": level, "gain": float(f"{suggested:.2g}") if suggested < 10 else float(int(suggested))}
    return out


def _episode_frames(reader, plan: _Plan, cfg: LeRobotExportConfig, pos: int, samples: list[int], times: list[float],
                    work: Path, ep_index: int, vstats: dict, progress) -> tuple[list[np.ndarray], np.ndarray, dict]:
    """Encode one episode's videos; return its raw rows per slot, the presence flags (see the module doc) and,
    with --tactile-window, the EpisodeWindows per raw slot."""
    ep = reader.episodes[pos]
    eid = ep["episode_id"]
    wanted = (JSON_MEMBER, *((RGB_MEMBER,) if plan.rgb else ()), *[raw_member(h) for h in plan.hands],
              *([tactile_member(h) for h in plan.hands] if cfg.maps else []))
    chunk, file = _chunk_file(ep_index)
    videos = {k: VideoWriter(work / VIDEO_PATH.format(video_key=k, chunk_index=chunk, file_index=file),
                             plan.fps, cfg.codec, cfg.crf, cfg.gop) for k in plan.video_keys}
    raw = [np.zeros((len(samples), *slot.grid), np.float32) for slot in plan.slots]
    present = np.zeros((len(samples), len(plan.present_names)), bool)
    slot_of = {h: next(k for k, s in enumerate(plan.slots) if s.hand == h and s.grid == plan.layout_grids[lid])
               for h, lid in ep["layouts"].items()}
    last_rgb = np.zeros((CANVAS, CANVAS, 3), np.uint8)
    cache: tuple[int, dict] | None = None            # a resampled episode may repeat a sample
    # a version that stores no maps (htdata/format/mapstorage.py): --maps renders them from the raw rows
    renderer = None if MapStorage.of(reader.manifest).stores_maps else RawMapRenderer(reader)
    first = reader.episode_range(pos)[0]
    windows = {k: EpisodeWindows(len(samples), cfg.tactile_window, plan.slots[k].grid)
               for k in range(len(plan.slots))} if cfg.tactile_window else {}   # a hand it lacks: all padding
    previous = first - 1                           # the stored frame of the previous exported frame
    for f, (i, t) in enumerate(zip(samples, times)):
        if cache is None or cache[0] != i:
            cache = (i, reader.read_sample(i, wanted)[2])
        members = cache[1]
        where = f"{reader.root}: {reader.key(i)} (episode {eid!r} frame {i - first})"
        if windows:   # the last frame also takes the rows of stored frames after it (a resampled end)
            last = first + reader.episode_range(pos)[1] - 1 if f == len(samples) - 1 else i
            _fill_windows(reader, windows, slot_of, members, previous, i, last, f, where)
        previous = i
        if plan.rgb:
            if RGB_MEMBER in members:
                last_rgb = decode_member(RGB_MEMBER, members[RGB_MEMBER], where)
                present[f, 0] = True
                vstats[RGB_KEY].add(last_rgb)
            videos[RGB_KEY].add(last_rgb, t, where)
        for hand, k in slot_of.items():
            if raw_member(hand) in members:
                row = paired_row(members, hand, where)
                if row.shape != plan.slots[k].grid:
                    raise DatasetError(f"{where}: {hand} raw row shaped {row.shape}, "
                                       f"expected {plan.slots[k].grid} (its layout's grid)")
                # NaN / Inf mark cells without a taxel in some sources: 0 (LeRobot stats and
                # normalisation would turn one NaN into NaN everywhere); finite values stay exact
                raw[k][f] = np.where(np.isfinite(row), row, 0.0)
                present[f, plan.present_col(k)] = True
        if cfg.maps:
            for hand in plan.hands:
                _add_map_frame(_hand_map(members, hand, where, renderer, pos), t, where, videos[map_key(hand)],
                               vstats[map_key(hand)], plan.maps_gain)
        if progress is not None:
            progress(1)
    for v in videos.values():
        v.close()
    return raw, present, windows


def _fill_windows(reader, windows: dict, slot_of: dict, members: dict, previous: int, i: int, last: int, f: int,
                  where: str) -> None:
    """Frame f's windows: the rows of stored frames previous+1 .. last (frame f is stored frame i, whose
    members are `members`; last > i only for the export's last frame)."""
    wanted = (JSON_MEMBER, *[raw_member(h) for h in slot_of])
    held = {hand: ([], []) for hand in slot_of}
    for j in range(previous + 1, last + 1):
        got = members if j == i else reader.read_sample(j, wanted)[2]
        for hand, (rows, times) in held.items():
            r, t = sample_rows(got, hand, where if j == i else f"{reader.root}: {reader.key(j)}")
            rows += r
            times += t
    t_frame = int(decode_member(JSON_MEMBER, members[JSON_MEMBER], where)["t_rgb_ns"])
    for hand, k in slot_of.items():
        windows[k].put(f, *held[hand], t_frame, where, hand)


def _hand_map(members: dict, hand: str, where: str, renderer: RawMapRenderer | None, episode: int):
    """The hand's map this frame: decoded, or rendered from its raw rows when not stored; None without one."""
    if renderer is not None:
        return renderer.render(episode, hand, members, where) if raw_member(hand) in members else None
    if tactile_member(hand) in members:
        return decode_member(tactile_member(hand), members[tactile_member(hand)], where)
    return None


def _add_map_frame(m: np.ndarray | None, t: float, where: str, video: VideoWriter, vstats: VideoStats,
                   gain: float = 1.0) -> None:
    """--maps: the canonical map as grey (value x gain x 255, clipped); black where the hand has no map this frame."""
    grey = np.zeros((CANVAS, CANVAS), np.uint8)
    if m is not None:
        grey = np.round(np.clip(np.nan_to_num(m) * np.float32(gain), 0.0, 1.0) * 255).astype(np.uint8)
    rgb = np.repeat(grey[..., None], 3, axis=2)
    video.add(rgb, t, where)
    if m is not None:
        vstats.add(rgb)


def _add_stats(stats: dict, plan: _Plan, raw: list[np.ndarray], cols: dict) -> None:
    """One episode into the running stats: raw features over real rows only (absent ones are fill)."""
    present = cols[PRESENT_KEY]
    values = {slot.key: raw[k][present[:, plan.present_col(k)]] for k, slot in enumerate(plan.slots)} | cols
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
