"""`htdata export lerobot` speed and size against htdata's own shards (a `make bench` section).

One export of the bench dataset (every source) to a scratch folder, timed end to end
(read + JPEG decode + H.264 encode + parquet + stats), then the same export with --maps.
Bytes per frame: the export's files (videos, parquet, meta) against the dataset's
shards + index (what htdata itself stores for the same frames, tactile maps included).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from htdata.benchmarks.tables import table
from htdata.export.lerobot import LeRobotExportConfig, export_lerobot
from htdata.read.reader import DatasetReader


def _bytes(paths) -> int:
    return sum(p.stat().st_size for p in paths if p.is_file())


def export_rows(dataset: Path, work: Path) -> dict:
    with DatasetReader(dataset) as reader:
        frames = len(reader)
    shard_bytes = _bytes((dataset / "shards").rglob("*")) + _bytes([dataset / "index.npy"])
    runs = []
    for maps in (False, True):
        out = work / ("lerobot_maps" if maps else "lerobot")
        t0 = time.perf_counter()
        summary = export_lerobot(LeRobotExportConfig(dataset=str(dataset), out=out, maps=maps, force=True))
        dt = time.perf_counter() - t0
        files = list(out.rglob("*"))
        video = _bytes(p for p in files if p.suffix == ".mp4")
        data = _bytes(p for p in files if p.suffix == ".parquet" and "data" in p.parts)
        total = _bytes(files)
        runs.append({"maps": maps, "frames": summary["frames"], "seconds": round(dt, 3),
                     "frames_per_s": round(summary["frames"] / dt, 1),
                     "bytes_per_frame": round(total / summary["frames"], 1),
                     "video_bytes_per_frame": round(video / summary["frames"], 1),
                     "parquet_bytes_per_frame": round(data / summary["frames"], 1)})
        shutil.rmtree(out, ignore_errors=True)
    return {"frames": frames, "htdata_bytes_per_frame": round(shard_bytes / frames, 1), "runs": runs}


def export_markdown(d: dict) -> list[str]:
    lines = table(d["runs"], [("maps", "--maps"), ("frames", "frames"), ("seconds", "seconds"),
                              ("frames_per_s", "frames/s"), ("bytes_per_frame", "bytes/frame (all files)"),
                              ("video_bytes_per_frame", "video bytes/frame"),
                              ("parquet_bytes_per_frame", "parquet bytes/frame")])
    return lines + ["", f"htdata's own shards + index: {d['htdata_bytes_per_frame']:,.0f} bytes/frame for the same "
                    f"{d['frames']} frames (JPEG q95 RGB, EXR maps, raw rows). The export keeps the raw rows "
                    "exactly and the RGB as H.264 (crf 18, keyframe every 2 frames).", ""]
