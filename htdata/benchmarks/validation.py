"""`htdata validate --deep` throughput at 1 and 2 worker processes."""

from __future__ import annotations

from pathlib import Path

from htdata.validate import validate_benchmark


def validate_rows(root: Path, workers: tuple[int, ...] = (1, 2)) -> list[dict]:
    rows = [validate_benchmark(root, workers=w) for w in workers]
    for r, w in zip(rows, workers):
        r["workers"] = w      # what was asked (the report may record it differently)
        r["scaling"] = r["frames_per_s"] / rows[0]["frames_per_s"]
    return rows
