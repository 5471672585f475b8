"""`htdata validate --deep` throughput at 1 and 2 worker processes."""

from __future__ import annotations

import time
from pathlib import Path

from htdata.validate import validate_dataset


def validate_benchmark(path, workers: int | None = None) -> dict:
    """Time a --deep validation: frames (samples) decoded and checked per second."""
    t0 = time.perf_counter()
    report = validate_dataset(path, deep=True, workers=workers)
    elapsed = time.perf_counter() - t0
    return {"frames": report["samples"], "seconds": elapsed,
            "frames_per_s": report["samples"] / elapsed if elapsed > 0 else float("inf"),
            "workers": report["params"].get("workers"), "ok": report["ok"]}


def validate_rows(root: Path, workers: tuple[int, ...] = (1, 2)) -> list[dict]:
    rows = [validate_benchmark(root, workers=w) for w in workers]
    for r, w in zip(rows, workers):
        r["workers"] = w      # what was asked (the report may record it differently)
        r["scaling"] = r["frames_per_s"] / rows[0]["frames_per_s"]
    return rows
