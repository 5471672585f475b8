"""`htdata view --save` speed and memory against episode length (a `make bench` section).

One moving two-hand TouchAnything episode per length (the peak-memory section's
episodes, `write_long_touchanything`: RGB, two 21x21 gloves with bend values),
ingested inline, then `htdata view DATASET --save OUT.rrd` run as a user runs it,
in a fresh interpreter that reports its own peak RSS (VmHWM), the seconds the
command took (rerun's import included; the interpreter's start not) and the CPU
seconds of the whole process (every thread; what the wall time would be on an
idle core, where a shared machine's load stretches the wall time). Each length
is viewed twice: "first" computes the dataset's stats for the colour scale (auto
contrast) and caches them, "again" finds them cached. Issue #38's target: a
600-frame episode saved in under 10 s; peak memory flat in the episode's length
(the episode is streamed, never held).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from htdata.benchmarks.ingest import write_long_touchanything
from htdata.benchmarks.tables import table
from htdata.ingest import Source, ingest
from htdata.ingest.pipeline import load_pipeline

TARGET_SECONDS_600 = 10.0
_VIEW_CHILD = """
import resource, sys, time
t0 = time.perf_counter()
from htdata.cli import main
rc = main(sys.argv[1:])
seconds = time.perf_counter() - t0
usage = resource.getrusage(resource.RUSAGE_SELF)   # every thread of this process, rerun's sink included
try:   # VmHWM: this process image's own peak (ru_maxrss keeps the forking parent's across exec)
    kb = next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith("VmHWM:"))
except OSError:
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print("VIEW_RESULT", seconds, usage.ru_utime + usage.ru_stime, kb, rc)
"""


def view_once(dataset: Path, out: Path) -> dict:
    """`htdata view DATASET --save OUT` in a fresh interpreter: its seconds, peak RSS and the file's size."""
    proc = subprocess.run([sys.executable, "-c", _VIEW_CHILD, "view", str(dataset), "--save", str(out)],
                          capture_output=True, text=True)
    line = [ln.split() for ln in proc.stdout.splitlines() if ln.startswith("VIEW_RESULT")]
    if proc.returncode != 0 or not line or line[0][4] != "0":
        raise RuntimeError(f"htdata view {dataset} --save {out} failed: {(proc.stderr or proc.stdout)[-2000:]}")
    _, seconds, cpu, rss_kb, _ = line[0]
    return {"seconds": float(seconds), "cpu_s": float(cpu), "peak_rss_mb": int(rss_kb) / 1024.0,
            "rrd_bytes": out.stat().st_size, "load_1m": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}


def view_rows(work: Path, lengths: tuple[int, ...], again: bool = True) -> dict:
    """Per length: ingest the episode, view it (twice with `again`); rows and the targets' inputs."""
    rows = []
    for n in lengths:
        src = work / f"long_touchanything_{n}"
        if not src.exists():
            write_long_touchanything(src, n)
        dataset = work / f"view_ds_{n}"
        if dataset.exists():
            shutil.rmtree(dataset)
        report = ingest([Source(pipeline=load_pipeline("touchanything"), root=src.resolve())], dataset, workers=0,
                        progress=False)
        if report["failures"] or int(report["samples"]) != n:
            raise RuntimeError(f"bench view: the {n}-frame episode did not ingest: {report['failures'][:3]}")
        for run in ("first", "again")[:2 if again else 1]:
            t0 = time.perf_counter()
            row = view_once(dataset, work / f"view_{n}.rrd")
            rows.append({"frames": n, "run": run, **row, "wall_s": time.perf_counter() - t0,
                         "frames_per_s": n / row["seconds"], "rrd_bytes_per_frame": row["rrd_bytes"] / n})
        shutil.rmtree(dataset)
        (work / f"view_{n}.rrd").unlink()
    base = rows[0]["peak_rss_mb"]
    for r in rows:
        r["rss_vs_shortest"] = r["peak_rss_mb"] / base
    return {"rows": rows, "target_seconds_600": TARGET_SECONDS_600, "cpus": os.cpu_count()}


def _load(value) -> str:
    return "unknown" if value is None else f"{value:.1f}"


def view_markdown(d: dict) -> list[str]:
    lines = ["`htdata view DATASET --save OUT.rrd` on one moving two-hand TouchAnything episode per length "
             "(RGB, two 21x21 gloves with bend), in a fresh interpreter: seconds of the command (rerun's import "
             "included), the CPU seconds of the whole process, the machine's load when it ended, its own peak RSS "
             "(VmHWM). 'first' computes and caches the stats of the auto colour "
             "scale; 'again' finds them cached.", ""]
    lines += table(d["rows"], [("frames", "episode frames"), ("run", "run"), ("seconds", "seconds"),
                               ("cpu_s", "CPU s (all threads)"), ("load_1m", "load (1 min)"),
                               ("frames_per_s", "frames/s"), ("peak_rss_mb", "peak RSS MiB"),
                               ("rss_vs_shortest", "RSS vs shortest"), ("rrd_bytes_per_frame", ".rrd bytes/frame")])
    at600 = [r for r in d["rows"] if r["frames"] == 600]
    if at600:
        worst = max(at600, key=lambda r: r["seconds"])
        lines.append(f"600-frame episode saved in {worst['seconds']:.1f} s at worst (target < "
                     f"{d['target_seconds_600']:.0f} s): {'met' if worst['seconds'] < d['target_seconds_600'] else 'MISSED'}"
                     f"; {worst['cpu_s']:.1f} CPU s, at load {_load(worst['load_1m'])} on "
                     f"{d['cpus']} cores.")
    growth = max(r["rss_vs_shortest"] for r in d["rows"])
    lines.append(f"Peak memory over {d['rows'][0]['frames']}..{d['rows'][-1]['frames']} frames: {growth:.2f}x the "
                 "shortest episode's (streamed in batches of frames, never held whole).")
    return lines + [""]
