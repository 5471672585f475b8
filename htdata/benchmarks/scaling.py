"""Ingest worker scaling, 1 -> N workers (N = the machine's usable cores by default).

`scaling_rows` ingests each adapter's part of the "medium" sample corpus
(3x small: ~60 units per adapter, so the unit count does not cap the
speed-up on a few cores) at 1 and at N workers, alternating, `reps` times; the speed-up is
the median of each pair's ratio. Every run's report timing splits the wall
time into the driver's phases (plan_s, run_s, commit_s) and the units'
in-worker seconds, so the fixed part is visible.

The 10M-frame projection is the driver section's (htdata/benchmarks/driver.py):
it measures the driver's serial work at two corpus sizes, so its growth per
frame is separated from its fixed cost; `driver_s_per_frame` here is only the
average at this one size.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.benchmarks.ingest import ingest_run


def scaling_rows(corpus: Path, work: Path, adapters: tuple[str, ...], workers: tuple[int, int] = (1, 2),
                 reps: int = 2) -> dict:
    """Per adapter: alternate `reps` ingests at workers[0] and workers[1]; speed-up = median pair ratio."""
    lo, hi = workers
    runs, summary = [], []
    for name in adapters:
        pairs = []
        for rep in range(reps):
            pair = {}
            for w in (lo, hi):
                run = ingest_run([(name, corpus / name)], work / f"scaling_{name}_w{w}", w)
                run["rep"] = rep
                runs.append(run)
                pair[w] = run
            pairs.append(pair)
        ratios = [p[hi]["frames_per_s"] / p[lo]["frames_per_s"] for p in pairs]
        run_ratios = [(p[hi]["frames"] / p[hi]["run_s"]) / (p[lo]["frames"] / p[lo]["run_s"]) for p in pairs]
        top = [p[hi] for p in pairs]
        summary.append({
            "adapter": name, "frames": top[0]["frames"], "units": top[0]["units"], "reps": reps,
            "workers_lo": lo, "workers_hi": hi,
            "frames_per_s_lo": float(np.median([p[lo]["frames_per_s"] for p in pairs])),
            "frames_per_s_hi": float(np.median([r["frames_per_s"] for r in top])),
            "scaling": float(np.median(ratios)), "scaling_reps": ratios,
            "run_phase_scaling": float(np.median(run_ratios)),
            "fixed_s_hi": float(np.median([r["plan_s"] + r["commit_s"] for r in top])),
            "core_s_per_frame_hi": float(np.median([r["worker_s"] / r["frames"] for r in top])),
            "core_s_per_frame_lo": float(np.median([p[lo]["worker_s"] / p[lo]["frames"] for p in pairs])),
            "driver_s_per_frame": float(np.median([(r["plan_s"] + r["commit_s"]) / r["frames"] for r in top])),
        })
    return {"runs": runs, "summary": summary}

