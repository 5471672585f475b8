"""Read a LeRobot v3.0 export with pyarrow + PyAV as LeRobot's format documents it; compare to htdata's reader.

    python tools/lerobot_check.py DATASET EXPORT [--windows 20] [--seed 0] [--json OUT]

What a LeRobot loader does, done by hand (no htdata code reads the export):
  meta/info.json            features, fps, data_path / video_path templates
  meta/episodes/*.parquet   per episode: dataset_from_index/to_index, data file, video file + from_timestamp
  meta/tasks.parquet        task_index -> task string (the pandas index)
  data/*.parquet            one row per frame
  videos/<key>/*.mp4        the frame of row r is the video frame whose time is from_timestamp + timestamp[r]
                            (LeRobot's lookup, tolerance 1e-4 s)
  delta_timestamps windows  {key: [-k/fps .. 0]} -> row indices clamped to the episode, *_is_pad flags

Checks against htdata's DatasetReader (matched through meta/htdata/episodes.jsonl):
  rows on the exact 1/fps grid, each holding the stored frame nearest its tick on the source clock;
  raw rows equal exactly (float32 bits; NaN/Inf cells exported as 0) where observation.present says real, zeros elsewhere;
  observation.present equals which members the htdata sample holds; task strings equal;
  every video frame decodes at its row's timestamp; RGB within the codec tolerance (measured, printed);
  windows equal htdata's frames row for row;
  --tactile-window exports: each episode's window rows (where ..._mask), in order, equal htdata's
  full-rate stream of that hand (htdata.read.rawstream.episode_stream), each row once, at its time.
Exit 0 when everything holds; otherwise one line per problem and exit 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq

from htdata.format.codec import decode_rgb
from htdata.format.table import RGB_MEMBER, raw_member
from htdata.read.rawstream import episode_stream, paired_row
from htdata.read.reader import DatasetReader

TOLERANCE_S = 1e-4           # LeRobotDataset's default tolerance_s
RGB_MEAN_ABS_MAX = 4.0       # H.264 crf 18 on 224x224 (yuv420p): measured mean |diff| ~1-2 levels
EGO = "observation.images.egocentric"   # absent from a glove-only export
RGB_P99_ABS_MAX = 40.0       # chroma subsampling at colour edges: the worst 1% of pixels


def read_export(root: Path) -> dict:
    info = json.loads((root / "meta/info.json").read_text())
    episodes = [r for f in sorted((root / "meta/episodes").rglob("*.parquet")) for r in pq.read_table(f).to_pylist()]
    episodes.sort(key=lambda r: r["episode_index"])
    tasks_table = pq.read_table(root / "meta/tasks.parquet").to_pydict()
    task_col = next(c for c in tasks_table if c != "task_index")
    tasks = dict(zip(tasks_table["task_index"], tasks_table[task_col]))
    files = sorted({(e["data/chunk_index"], e["data/file_index"]) for e in episodes})
    data = [pq.read_table(root / info["data_path"].format(chunk_index=c, file_index=f)) for c, f in files]
    import pyarrow as pa
    table = pa.concat_tables(data)
    return {"info": info, "episodes": episodes, "tasks": tasks, "table": table}


def decode_video(path: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """(frame times in s, RGB frames) of one mp4, in presentation order."""
    times, frames = [], []
    with av.open(str(path)) as c:
        for frame in c.decode(video=0):
            times.append(float(frame.pts * frame.time_base))
            frames.append(frame.to_ndarray(format="rgb24"))
    order = np.argsort(times)
    return np.asarray(times)[order], [frames[i] for i in order]


def frame_at(times: np.ndarray, t: float) -> int | None:
    """LeRobot's lookup: the closest frame, None when it is further than the tolerance."""
    k = int(np.argmin(np.abs(times - t)))
    return k if abs(times[k] - t) < TOLERANCE_S else None


def check(dataset: Path, export: Path, windows: int, seed: int) -> tuple[list[str], dict]:
    problems: list[str] = []
    ex = read_export(export)
    info, table = ex["info"], ex["table"]
    feats = info["features"]
    fps = info["fps"]
    raw_keys = [k for k in feats if k.startswith("observation.tactile.") and k.rsplit(".", 1)[1].startswith("raw")]
    video_keys = [k for k in feats if feats[k]["dtype"] == "video"]
    present_names = feats["observation.present"]["names"]
    cols = {k: table.column(k).to_pylist() for k in ("timestamp", "frame_index", "episode_index", "index",
                                                     "task_index", "observation.present", "htdata.frame_index")}
    raws = {k: np.asarray(table.column(k).to_pylist(), np.float32).reshape(len(table), *feats[k]["info"]["grid"])
            for k in raw_keys}   # stored flat, row-major; info.grid restores the glove's shape
    ids = {r["episode_index"]: r for r in map(json.loads, (export / "meta/htdata/episodes.jsonl").read_text().split("\n")[:-1])}
    reader = DatasetReader(dataset)
    rgb_diffs = []
    if len(table) != info["total_frames"]:
        problems.append(f"data has {len(table)} rows, info.json total_frames {info['total_frames']}")
    if cols["index"] != list(range(len(table))):
        problems.append("global index column is not 0..N-1")
    videos = {}
    grid = {"repeated": 0, "skipped": 0}      # frames a row holds twice / no row holds (0 on a regular clock)
    for ep in ex["episodes"]:
        e = ep["episode_index"]
        lo, hi = ep["dataset_from_index"], ep["dataset_to_index"]
        htd = ids[e]
        pos = reader.episode_position(htd["episode_id"])
        first, n = reader.episode_range(pos)
        where = f"episode {e} ({htd['episode_id']!r})"
        if ex["tasks"][cols["task_index"][lo]] != reader.episodes[pos]["task"] or ep["tasks"] != [reader.episodes[pos]["task"]]:
            problems.append(f"{where}: task differs from htdata's {reader.episodes[pos]['task']!r}")
        # rows sit on the 1/fps grid; each names the stored frame nearest its tick on the source clock
        t_src = np.array([json.loads(reader.sample(first + i, ("json",))["json"])["t_rgb_ns"] for i in range(n)])
        t_src = (t_src - t_src[0]) / 1e9
        ts = np.asarray(cols["timestamp"][lo:hi], np.float64)
        if not np.allclose(ts, np.arange(hi - lo) / fps, atol=1e-6):
            problems.append(f"{where}: timestamps are not k/fps")
        frames_used = np.asarray(cols["htdata.frame_index"][lo:hi])
        nearest = np.abs(t_src[None, :] - ts[:, None]).argmin(1)
        if not np.array_equal(np.abs(t_src[frames_used] - ts), np.abs(t_src[nearest] - ts)):
            problems.append(f"{where}: a row does not hold the stored frame nearest its tick")
        grid["repeated"] += int(len(frames_used) - len(set(frames_used.tolist())))
        grid["skipped"] += int(n - len(set(frames_used.tolist())))
        for key in video_keys:
            path = export / info["video_path"].format(video_key=key, chunk_index=ep[f"videos/{key}/chunk_index"],
                                                      file_index=ep[f"videos/{key}/file_index"])
            videos[(e, key)] = (decode_video(path), ep[f"videos/{key}/from_timestamp"])
        # a glove-only export has no egocentric video (nor an "egocentric" present flag)
        (vt, vframes), from_ts = videos.get((e, EGO), ((None, None), 0.0))
        layouts = htd["layouts"]
        for r in range(lo, hi):
            f = cols["htdata.frame_index"][r]
            members = reader.sample(first + f)
            fw = f"{where} frame {f}"
            present = dict(zip(present_names, cols["observation.present"][r]))
            if present.get("egocentric", False) != (RGB_MEMBER in members):
                problems.append(f"{fw}: present[egocentric]={present.get('egocentric')} but htdata RGB member "
                                f"{'present' if RGB_MEMBER in members else 'absent'}")
            k = frame_at(vt, from_ts + cols["timestamp"][r]) if vt is not None else None
            if vt is not None and k is None:
                problems.append(f"{fw}: no video frame within {TOLERANCE_S} s of t={cols['timestamp'][r]:.6f}")
            elif k is not None and RGB_MEMBER in members:
                ref = decode_rgb(members[RGB_MEMBER]).astype(np.int16)
                rgb_diffs.append(np.abs(vframes[k].astype(np.int16) - ref).ravel())
            for key in raw_keys:
                name = key.removeprefix("observation.")
                hand = key.split(".")[2]
                real = present[name]
                row = raws[key][r]
                held = (raw_member(hand) in members and hand in layouts
                        and key in (f"observation.tactile.{hand}.raw",
                                    f"observation.tactile.{hand}.raw_{_grid_tag(reader, layouts[hand])}"))
                if real != held:
                    problems.append(f"{fw}: present[{name}]={real}, htdata sample {'has' if held else 'lacks'} it")
                elif real:
                    want = _exported(paired_row(members, hand, fw))
                    if want.shape != row.shape or not np.array_equal(want.view(np.uint32), row.view(np.uint32)):
                        problems.append(f"{fw}: {key} differs from htdata's raw row")
                elif np.any(row != 0):
                    problems.append(f"{fw}: {key} is not zero where not present")
    diffs = np.concatenate(rgb_diffs) if rgb_diffs else np.zeros(1)
    rgb = {"frames": len(rgb_diffs), "mean_abs": round(float(diffs.mean()), 3),
           "p99_abs": float(np.percentile(diffs, 99)), "max_abs": int(diffs.max())}
    if rgb["mean_abs"] > RGB_MEAN_ABS_MAX or rgb["p99_abs"] > RGB_P99_ABS_MAX:
        problems.append(f"RGB beyond the codec tolerance: {rgb} (limits mean {RGB_MEAN_ABS_MAX}, p99 {RGB_P99_ABS_MAX})")
    win = check_windows(reader, ex, cols, raws, raw_keys, videos, ids, windows, seed, problems)
    item = one_item(ex, cols, raws, raw_keys, videos, fps)
    full_rate = check_tactile_windows(reader, ex, ids, raw_keys, problems)
    return problems, {"rows": len(table), "episodes": len(ex["episodes"]), "rgb_vs_htdata": rgb, "grid": grid,
                      "windows_checked": win, "item": item, "tactile_window_rows_checked": full_rate}


def check_tactile_windows(reader, ex, ids, raw_keys, problems) -> int:
    """--tactile-window exports: every full-rate glove row htdata serves, once, in order, at its time."""
    feats, table = ex["info"]["features"], ex["table"]
    checked = 0
    for key in raw_keys:
        stem = key.replace(".raw", ".window", 1)
        if stem not in feats:
            continue
        k, rows, cols = feats[stem]["info"]["window"]
        hand = key.split(".")[2]
        values = np.asarray(table.column(stem).to_pylist(), np.float32).reshape(len(table), k, rows, cols)
        mask = np.asarray(table.column(f"{stem}_mask").to_pylist(), bool)
        dt = np.asarray(table.column(f"{stem}_dt").to_pylist(), np.float64)
        src = np.asarray(table.column("htdata.frame_index").to_pylist(), np.int64)
        for ep in ex["episodes"]:
            lo, hi = ep["dataset_from_index"], ep["dataset_to_index"]
            eid = ids[ep["episode_index"]]["episode_id"]
            got = values[lo:hi][mask[lo:hi]]
            try:
                want = episode_stream(reader, eid, hand)
            except ValueError:          # the episode has no rows of this hand: every slot must be padding
                want = None
            if want is None or tuple(want.rows.shape[1:]) != (rows, cols):   # not this grid's (or no) rows
                if mask[lo:hi].any():
                    problems.append(f"{eid}: {stem} holds rows but htdata has no {hand} rows of grid {rows}x{cols}")
                continue
            if got.shape != want.rows.shape or not np.array_equal(got, _exported(want.rows)):
                problems.append(f"{eid}: {stem} rows {got.shape} differ from htdata's {hand} stream {want.rows.shape}")
                continue
            first = reader.episode_range(eid)[0]
            t_frame = np.array([json.loads(reader.sample(first + int(f), ("json",))["json"])["t_rgb_ns"]
                                for f in src[lo:hi]], np.float64)
            t_rows = (t_frame[:, None] + dt[lo:hi] * 1e9)[mask[lo:hi]]
            if not np.allclose(t_rows, want.t_ns, atol=2_000):
                problems.append(f"{eid}: {stem}_dt does not give htdata's row times (worst "
                                f"{np.abs(t_rows - want.t_ns).max():.0f} ns)")
            checked += len(got)
    return checked


def _exported(row: np.ndarray) -> np.ndarray:
    """The export's documented rule: finite values as stored (float32), NaN/Inf (no taxel) as 0."""
    row = row.astype(np.float32)
    return np.where(np.isfinite(row), row, np.float32(0))


def _grid_tag(reader: DatasetReader, layout_id: str) -> str:
    g = reader.layout(layout_id)["grid"]
    return f"{g[0]}x{g[1]}"


def check_windows(reader, ex, cols, raws, raw_keys, videos, ids, count, seed, problems) -> int:
    """delta_timestamps = {key: [-k/fps, ..., 0]} windows, resolved the way LeRobotDataset does, vs htdata's frames."""
    fps = ex["info"]["fps"]
    k = 3
    deltas = [d / fps for d in range(-k, 1)]
    delta_idx = [round(d * fps) for d in deltas]
    rng = np.random.default_rng(seed)
    checked = 0
    for r in rng.choice(len(cols["index"]), size=min(count, len(cols["index"])), replace=False):
        r = int(r)
        e = cols["episode_index"][r]
        ep = ex["episodes"][e]
        lo, hi = ep["dataset_from_index"], ep["dataset_to_index"]
        query = [max(lo, min(hi - 1, r + d)) for d in delta_idx]
        pad = [(r + d < lo) or (r + d >= hi) for d in delta_idx]
        f = cols["frame_index"][r]
        eid = ids[e]["episode_id"]
        if any(pad):
            if f >= k:
                problems.append(f"window at episode {e} row {f}: padded although {k} earlier rows exist")
            continue
        first = reader.episode_range(eid)[0]
        ref = [reader.decoded(first + cols["htdata.frame_index"][q]) for q in query]
        (vt, vframes), from_ts = videos.get((e, EGO), ((None, None), 0.0))
        for q, sample in zip(query, ref):
            kf = frame_at(vt, from_ts + cols["timestamp"][q]) if vt is not None else None
            if vt is not None and kf is None:
                problems.append(f"window at episode {e} frame {f}: row {q} has no video frame")
            elif kf is not None and "rgb" in sample and np.abs(vframes[kf].astype(np.int16) - sample["rgb"]).mean() > RGB_MEAN_ABS_MAX:
                problems.append(f"window at episode {e} frame {f}: row {q} RGB is not htdata's frame")
            for key in raw_keys:
                hand = key.split(".")[2]
                name = key.removeprefix("observation.")
                idx = ex["info"]["features"]["observation.present"]["names"].index(name)
                if cols["observation.present"][q][idx] and hand in sample.get("raw", {}):
                    meta = sample["meta"]
                    rows = sample["raw"][hand]
                    at = (meta.get("raw_paired") or {}).get(hand, 0) if rows.shape[0] > 1 else 0
                    if not np.array_equal(_exported(rows[at]).view(np.uint32), raws[key][q].view(np.uint32)):
                        problems.append(f"window at episode {e} frame {f}: row {q} {key} differs")
        checked += 1
    return checked


def one_item(ex, cols, raws, raw_keys, videos, fps) -> dict:
    """What a LeRobotDataset item holds for one row, read by hand (shapes, task, a few values)."""
    r = next(i for i, p in enumerate(cols["observation.present"]) if all(p[:2]))
    e = cols["episode_index"][r]
    item = {"index": r, "episode_index": e, "frame_index": cols["frame_index"][r],
            "timestamp": round(cols["timestamp"][r], 6), "task": ex["tasks"][cols["task_index"][r]]}
    if (e, EGO) in videos:
        (vt, vframes), from_ts = videos[(e, EGO)]
        frame = vframes[frame_at(vt, from_ts + cols["timestamp"][r])]
        item[EGO] = f"{list(frame.shape)} uint8, mean {frame.mean():.1f}"
    item["observation.present"] = dict(zip(ex["info"]["features"]["observation.present"]["names"],
                                           cols["observation.present"][r]))
    for key in raw_keys:
        row = raws[key][r]
        item[key] = f"{list(row.shape)} float32, min {row.min():.1f} max {row.max():.1f} sum {row.sum():.1f}"
    return item


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("dataset", type=Path)
    p.add_argument("export", type=Path)
    p.add_argument("--windows", type=int, default=20, help="delta_timestamps windows checked (default 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None, help="also write the summary here")
    args = p.parse_args(argv)
    problems, summary = check(args.dataset, args.export, args.windows, args.seed)
    for line in problems[:50]:
        print(f"FAIL {line}")
    print(json.dumps(summary, indent=1))
    if args.json:
        args.json.write_text(json.dumps({"problems": problems, **summary}, indent=1))
    print(f"lerobot-check: {'OK' if not problems else f'{len(problems)} problem(s)'}: {summary['rows']} rows, "
          f"{summary['episodes']} episodes; RGB vs htdata {summary['rgb_vs_htdata']}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
