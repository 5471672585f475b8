"""Read paths of a committed dataset vs the bare decode bound; index load at scale.

Every access pattern decodes the same kind of sample (JPEG + EXR members);
the bound decodes member bytes already in memory, so ours/bound says what
seeks, reads, tar header checks and tensor building cost on top of decoding.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from htdata.codec import decode_rgb, decode_tactile
from htdata.manifest import index_load_benchmark
from htdata.reader import DatasetReader


def _rate(n: int, seconds: float) -> float:
    return n / seconds if seconds > 0 else 0.0


def decode_bound(reader: DatasetReader, indices: np.ndarray) -> dict:
    """Samples/s of json + JPEG + EXR decode with every member already in memory."""
    members = [reader.sample(int(i)) for i in indices]

    def decode_all() -> None:
        for m in members:
            json.loads(m["json"])
            decode_rgb(m["rgb.jpg"])
            for suffix, data in m.items():
                if suffix.startswith("tactile_"):
                    decode_tactile(data)

    decode_all()   # warm-up: codec libraries initialise lazily on first use
    best = float("inf")
    for _ in range(2):   # best of 2: the bound is the least noisy pass
        t0 = time.perf_counter()
        decode_all()
        best = min(best, time.perf_counter() - t0)
    return {"samples": len(members), "samples_per_s": _rate(len(members), best)}


def loader_rows(root: Path, n_random: int, n_windows: int, seed: int = 0) -> dict:
    from htdata.torchdata import TactileFrameDataset, TactileStream, TactileWindowDataset

    reader = DatasetReader(root)
    n = len(reader)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, size=min(n_random, n))
    bound = decode_bound(reader, idx)
    rows = []

    def add(name: str, items: int, samples: int, seconds: float) -> None:
        rows.append({"access": name, "items": items, "samples_decoded": samples, "seconds": seconds,
                     "samples_per_s": _rate(samples, seconds),
                     "ratio_to_bound": _rate(samples, seconds) / bound["samples_per_s"]})

    fresh = DatasetReader(root)
    t0 = time.perf_counter()
    for i in idx:
        fresh.decoded(int(i))
    add("reader random decoded(i)", len(idx), len(idx), time.perf_counter() - t0)

    t0 = time.perf_counter()
    for i in idx:
        fresh.sample(int(i))
    add("reader random sample(i) bytes only", len(idx), len(idx), time.perf_counter() - t0)

    eligible = [(p, f) for p, ep in enumerate(reader.episodes) for f in range(2, int(ep["num_frames"]))]
    picks = rng.choice(len(eligible), size=min(n_windows, len(eligible)), replace=False) if eligible else []
    t0 = time.perf_counter()
    for k in picks:
        fresh.window(eligible[k][0], eligible[k][1], 2)
    add("reader window k=2 (3 frames)", len(picks), 3 * len(picks), time.perf_counter() - t0)

    t0, count = time.perf_counter(), 0
    for _ in fresh.iter_samples(decode=True):
        count += 1
    add("reader stream iter_samples", count, count, time.perf_counter() - t0)

    frames = TactileFrameDataset(root)
    fidx = rng.integers(0, len(frames), size=min(n_random, len(frames)))
    t0 = time.perf_counter()
    for i in fidx:
        frames[int(i)]
    add("TactileFrameDataset random item", len(fidx), len(fidx), time.perf_counter() - t0)

    windows = TactileWindowDataset(root, window=3)
    widx = rng.integers(0, len(windows), size=min(n_windows, len(windows))) if len(windows) else []
    t0 = time.perf_counter()
    for i in widx:
        windows[int(i)]
    add("TactileWindowDataset item (3 frames)", len(widx), 3 * len(widx), time.perf_counter() - t0)

    stream = TactileStream(root)
    t0, count = time.perf_counter(), 0
    for _ in stream:
        count += 1
    add("TactileStream (one worker)", count, count, time.perf_counter() - t0)
    return {"samples_in_dataset": n, "bound": bound, "rows": rows}


def index_rows(rows_counts: tuple[int, ...], tmpdir: Path) -> list[dict]:
    out = []
    for n in rows_counts:
        r = index_load_benchmark(n, tmpdir)
        (Path(tmpdir) / "bench_index.npy").unlink(missing_ok=True)
        out.append(r)
    return out
