"""Appending one episode to datasets of N and 10N episodes: wall time and bytes written.

A dataset grows daily, so adding one session must cost that session, not the
dataset. Each size gets its own dataset of N small native recordings
(ingested once, inline), then one more recording is ingested into it. We
time that second ingest and count the bytes of every file it created or
changed (shards, version files, the pointer, the report). The target is
that time and bytes stay nearly flat from N to 10N. Format 3 rewrote the
index and the episode file per version (O(index)); format 4 writes the
segment the new unit joins and a manifest of one entry per segment
(htdata/store/segments.py).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

from htdata.ingest import Source, ingest
from htdata.ingest.pipeline import load_pipeline
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording

FRAMES = 8           # per recording: small, so the datasets build fast and the append is dominated by overheads
PERIOD_NS = 33_333_333


def write_recordings(root: Path, names: list[str]) -> None:
    t = np.arange(FRAMES, dtype=np.int64) * PERIOD_NS
    for k, name in enumerate(names):
        values = np.full((FRAMES, 16, 16), 1536.0 + k % 7, np.float32)
        frames = [np.full((48, 48, 3), (k * 37) % 255, np.uint8)] * FRAMES
        write_native_recording(root / name, NativeRecording(
            task="grasp", scene="lab", video_storage="jpeg", video_frames=frames, video_timestamps_ns=t,
            hands={"right": NativeHand("opentouch_right_16x16", values, t)}))


def file_state(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in root.rglob("*") if p.is_file()}


def append_row(work: Path, n: int) -> dict:
    """Ingest n recordings, then time the ingest of one more; bytes of new or changed files."""

    base = work / f"append_{n}"
    if base.exists():
        shutil.rmtree(base)
    raw, out = base / "raw", base / "ds"
    write_recordings(raw, [f"rec_{i:05d}" for i in range(n)])
    source = [Source(load_pipeline("native"), raw.resolve())]
    ingest(source, out, workers=0, progress=False)
    before = file_state(out)
    write_recordings(raw, ["rec_new"])
    t0 = time.perf_counter()
    report = ingest(source, out, workers=0, progress=False)
    seconds = time.perf_counter() - t0
    after = file_state(out)
    written = {k: v[0] for k, v in after.items() if before.get(k) != v}
    return {"episodes_before": n, "frames_before": n * FRAMES, "seconds": seconds,
            "units_run": report["units_run"], "episodes_unchanged": report["episodes_unchanged"],
            "bytes_written": sum(written.values()),
            "bytes_shards": sum(v for k, v in written.items() if k.startswith("shards/")),
            "bytes_index_and_episodes": sum(v for k, v in written.items()     # format 3's files, 4's segments
                                            if k.endswith(("index.npy", "episodes.jsonl")) or k.startswith("segments/")),
            "files_written": len(written)}


def append_rows(work: Path, sizes: tuple[int, ...]) -> dict:
    rows = [append_row(work, n) for n in sizes]
    small, large = rows[0], rows[-1]
    return {"rows": rows, "frames_per_recording": FRAMES,
            "time_ratio_large_over_small": large["seconds"] / small["seconds"],
            "bytes_ratio_large_over_small": large["bytes_written"] / small["bytes_written"]}
