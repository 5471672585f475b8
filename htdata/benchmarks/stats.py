"""`htdata stats` speed against the loader's tactile-only decode rate, and its incremental cost.

The issue's target: computing stats must be at least as fast as the loader's
tactile-only decode (EXR maps, streamed shard by shard, no JPEG). Stats read
the raw rows where the dataset stores them (format 3: a small npy per hand,
normalised under the episode's calibration) and the maps otherwise; the
"from raw" column says which. Both are timed in this one run on the same
dataset; `stats_benchmark` (cold, warm and one-episode-appended runs) uses a
temporary cache.
"""

from __future__ import annotations

import time
from pathlib import Path

from htdata.format.table import HANDS, tactile_member
from htdata.inspect.stats import stats_benchmark
from htdata.read.reader import DatasetReader


def tactile_decode_rate(root: Path) -> dict:
    """Frames/s of streaming every sample and decoding only its tactile maps."""
    with DatasetReader(root) as reader:
        wanted = tuple(tactile_member(h) for h in HANDS)
        t0 = time.perf_counter()
        n = sum(1 for _ in reader.iter_samples(decode=True, suffixes=wanted))
        dt = time.perf_counter() - t0
    return {"frames": n, "seconds": dt, "frames_per_s": n / dt if dt > 0 else float("inf")}


def stats_rows(root: Path) -> dict:
    decode = tactile_decode_rate(root)
    runs = stats_benchmark(root)
    return {"tactile_decode": decode, "runs": runs,
            "cold_over_decode": runs["cold"]["frames_per_s"] / decode["frames_per_s"]}
