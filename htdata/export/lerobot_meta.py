"""The meta/ files of a LeRobot v3.0 export: info.json, stats.json, tasks.parquet, episodes, meta/htdata/."""

from __future__ import annotations

import json
from pathlib import Path

from htdata.store import storage
from htdata.store.confine import inside

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000               # files per chunk folder (LeRobot's default)
DATA_FILE_MB = 100               # data parquet rolled at this size (LeRobot's default)
VIDEO_FILE_MB = 200              # stated in info.json; the export writes one video file per episode
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
HTDATA_META = "meta/htdata"


def part_of(plan, eid: str) -> str | None:
    """The split part episode `eid` is exported in (None without a split, or when no part holds it)."""
    for part, ids in plan.parts.items():
        if eid in ids:
            return part
    return None


def write_meta(reader, plan, cfg, work: Path, feats, stats, vstats, tasks, episode_rows, frames, pa, pq) -> None:
    """Write meta/: episodes parquet, tasks.parquet, stats.json, info.json and htdata's own meta/htdata.

    Args:
        reader: the exported version, open.
        plan: the export's plan (htdata/export/lerobot_plan.py `plan_export`).
        cfg: the export's settings.
        work: the export's work folder (meta/ is written under it).
        feats: the feature table (`features(plan)`).
        stats: feature name -> `FeatureStats` of the non-video features.
        vstats: video key -> `VideoStats`.
        tasks: task string -> task index, in index order.
        episode_rows: one dict per exported episode: the rows of meta/episodes.
        frames: rows written in all.
        pa: the pyarrow module.
        pq: pyarrow.parquet.
    """
    meta = work / "meta"
    meta.mkdir(exist_ok=True)
    # episodes: one parquet (a row per episode is small)
    path = work / EPISODES_PATH.format(chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), path)
    # tasks: LeRobot reads it with pandas, the task string as the index
    task_table = pa.table({"task_index": pa.array(list(tasks.values()), pa.int64()),
                           "task": pa.array(list(tasks), pa.string())})
    pandas_meta = {"index_columns": ["task"], "column_indexes": [], "pandas_version": "2.2.0", "creator": None,
                   "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
                                "numpy_type": "int64", "metadata": None},
                               {"name": None, "field_name": "task", "pandas_type": "unicode",
                                "numpy_type": "object", "metadata": None}]}
    task_table = task_table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})
    pq.write_table(task_table, meta / "tasks.parquet")
    # stats
    all_stats = {k: s.result() for k, s in stats.items()} | {k: s.result() for k, s in vstats.items()}
    (meta / "stats.json").write_text(json.dumps({k: v for k, v in all_stats.items() if v is not None}, indent=1))
    # info
    if plan.parts:
        splits, start = {}, 0
        for part, ids in plan.parts.items():
            splits[part] = f"{start}:{start + len(ids)}"
            start += len(ids)
    else:
        splits = {"train": f"0:{len(plan.positions)}"}   # LeRobot's convention for "the whole dataset"
    info = {"codebase_version": CODEBASE_VERSION, "robot_type": "tactile_glove",
            "total_episodes": len(plan.positions), "total_frames": frames, "total_tasks": len(tasks),
            "chunks_size": CHUNKS_SIZE, "data_files_size_in_mb": DATA_FILE_MB,
            "video_files_size_in_mb": VIDEO_FILE_MB, "fps": plan.fps, "splits": splits,
            "data_path": DATA_PATH, "video_path": VIDEO_PATH, "features": feats}
    (meta / "info.json").write_text(json.dumps(info, indent=2))
    write_htdata_meta(reader, plan, cfg, work / HTDATA_META)


def write_htdata_meta(reader, plan, cfg, dest: Path) -> None:
    """What LeRobot has no place for: masks (constant per glove), layouts, split assignment, episode ids.

    Args:
        reader: the exported version, open.
        plan: the export's plan.
        cfg: the export's settings.
        dest: the folder to create and write (meta/htdata of the work folder).
    """
    dest.mkdir(parents=True)
    manifest = reader.manifest
    for hand in plan.hands:
        for layout_id in plan.layouts[hand]:
            entry = manifest["layouts"][layout_id]
            for name in ("file", "coverage"):
                if entry.get(name):
                    src = inside(reader.root, entry[name], f"layouts.{layout_id}.{name}")
                    ext = Path(entry[name]).suffix
                    (dest / f"layout_{layout_id}{'_coverage' if name == 'coverage' else ''}{ext}").write_bytes(
                        storage.read_bytes(src))
    canonical = manifest.get("canonical", {})
    for name, fname in (("regions", "region_map.png"), ("parts", "part_map.png"), ("file", "canonical_hand.json")):
        if canonical.get(name):
            (dest / fname).write_bytes(storage.read_bytes(inside(reader.root, canonical[name], f"canonical.{name}")))
    if plan.split_doc is not None:
        doc = {"split": cfg.split, "exported_parts": list(plan.parts), "assignment": plan.split_doc}
        (dest / "split.json").write_text(json.dumps(doc, indent=1))
    with open(dest / "episodes.jsonl", "w") as f:
        for ep_index, pos in enumerate(plan.positions):
            ep = reader.episodes[pos]
            f.write(json.dumps({"episode_index": ep_index, "episode_id": ep["episode_id"], "task": ep["task"],
                                "scene": ep.get("scene"), "source": ep.get("source"), "layouts": ep["layouts"],
                                "part": part_of(plan, ep["episode_id"]), "htdata_frames": ep["num_frames"]}) + "\n")
    (dest / "README.txt").write_text(
        f"Exported by htdata from {reader.root} version {reader.version}.\n"
        "layout_<id>.json: the glove layout (raw grid, live cells, value range) of each raw feature;\n"
        "layout_<id>_coverage.png: where that glove covers the canonical 224x224 hand (0/1);\n"
        "region_map.png / part_map.png: canonical place and part ids (thumb=1 .. palm=6);\n"
        "split.json: the full split assignment (when exported with --split); episodes.jsonl: htdata ids.\n")
