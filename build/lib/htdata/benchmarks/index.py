"""index.npy at scale: open time and memory of a synthetic 1M / 10M-row index (mmap vs full load)."""

from __future__ import annotations

import gc
import os
import time
from pathlib import Path

import numpy as np

from htdata.format import INDEX_DTYPE


def synthetic_index(n_rows: int, path: str | os.PathLike, samples_per_shard: int = 1000,
                    frames_per_episode: int = 500) -> Path:
    """Write a plausible index.npy of `n_rows` rows (for load-time benchmarks)."""
    path = Path(path)
    rows = np.zeros(n_rows, dtype=INDEX_DTYPE)
    i = np.arange(n_rows, dtype=np.uint64)
    sample_bytes = 512 * 8 + 2048 + 26 * 1024 + 18 * 1024
    rows["shard"] = i // samples_per_shard
    rows["offset"] = (i % samples_per_shard) * sample_bytes
    rows["episode"] = i // frames_per_episode
    rows["frame"] = i % frames_per_episode
    rows["size_json"] = 300
    rows["size_rgb"] = 26_000
    rows["size_tactile_right"] = 17_600
    np.save(path, rows, allow_pickle=False)
    return path


def index_load_benchmark(n_rows: int, tmpdir: str | os.PathLike) -> dict:
    """Write a synthetic index, then time mmap and full loads; report RSS growth."""
    import psutil

    path = synthetic_index(n_rows, Path(tmpdir) / "bench_index.npy")
    proc = psutil.Process()
    gc.collect()
    rss0 = proc.memory_info().rss
    t0 = time.perf_counter()
    rows = np.load(path, mmap_mode="r")
    first_touch = int(rows["episode"][n_rows // 2])  # touch one page so the map is real
    t1 = time.perf_counter()
    rss_mmap = proc.memory_info().rss
    del rows
    gc.collect()
    t2 = time.perf_counter()
    full = np.load(path)
    t3 = time.perf_counter()
    rss_full = proc.memory_info().rss
    del full
    return {
        "rows": n_rows,
        "file_bytes": path.stat().st_size,
        "mmap_load_ms": (t1 - t0) * 1e3,
        "mmap_rss_delta_mb": (rss_mmap - rss0) / 2**20,
        "full_load_ms": (t3 - t2) * 1e3,
        "full_rss_delta_mb": (rss_full - rss0) / 2**20,
        "probe_episode": first_touch,
    }


def index_rows(rows_counts: tuple[int, ...], tmpdir: Path) -> list[dict]:
    """One row per index size; each synthetic file is removed before the next is written."""
    out = []
    for n in rows_counts:
        out.append(index_load_benchmark(n, tmpdir))
        (Path(tmpdir) / "bench_index.npy").unlink(missing_ok=True)
    return out
