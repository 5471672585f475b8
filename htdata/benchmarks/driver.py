"""The ingest driver's serial work per frame at two corpus sizes, and HT-Bench (10M frames) on 64 cores from it.

Workers scale with cores; the driver does not: planning (discovery, layouts, the
append plan, the units), the commit (index, records, manifest) and, while the
units run, receiving their records. `driver_rows` ingests each adapter's part of
two sample corpora (tiny and medium by default: ~20x the frames, episodes of the
same shape) at N workers, `reps` times, and reads the driver's phases from each
report: plan_s + commit_s (wall) and the driver process's own CPU seconds per
phase (plan/run/commit_cpu_s: its workers not counted). On a shared machine the
wall seconds include waiting for a core; the CPU basis (the driver's CPU and the
workers' CPU, worker_cpu_s) is what a machine of one's own would spend, so both
projections are given. The serial GROWTH per frame is the slope between the sizes, (big - small) / (frames_big - frames_small),
medians over reps (after one warm-up ingest per adapter, not counted); the FIXED
part is what the small size leaves at zero frames.

`project` turns them into `frames` on `cores`: serial = fixed + growth x frames;
work = frames x the core seconds per frame measured in the workers at N workers
(the big corpus) / cores; the driver's run-phase CPU (receiving the records,
progress, its idle polling: an upper bound) per frame at the big size only
matters if it is slower than that, since it overlaps the workers: wall = serial
+ max(work, run CPU per frame x frames); speed-up = (frames x core s/frame +
serial) / wall. Target >= 55x on 64 cores; at ~7 ms of core time per frame that needs a
growth <= ~0.02 ms per frame. Not modelled (outside one machine): storage
bandwidth at 64 workers, Ray's per-task scheduling (milliseconds per unit, units
are episodes: ~10^5 for 10M frames, so ~0.01 ms per frame if serial), a slower
shared filesystem for the driver's metadata reads (discovery, the commit's
writes).

The glove rest an ingest pools for a raw-count glove without a `[normalise]` table
(htdata/ingest/gloverest.py) reads at most POOL_MAX recordings per glove: a bounded
cost, not a growth. The tiny corpus pools none (too few recordings) and the bigger one
some, so it is taken out of the slope (serial minus rest_s / rest_cpu_s, which the report
times) and put back as a fixed term: its cost per pooled recording x POOL_MAX per glove.
`episode_frames` (lo, hi): both corpora written with episodes of that many frames
(`htdata sample --episode-frames`, `htdata bench --driver-episode-frames`): the
driver's work is per episode, so its growth per frame depends on the episode length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.benchmarks.ingest import ingest_run
from htdata.benchmarks.tables import table
from htdata.glove.pooledrest import POOL_MAX

HT_BENCH_FRAMES = 10_000_000
CLUSTER_CORES = 64
TARGET_SPEEDUP = 55.0               # issue 37: projected 10M-frame speed-up on 64 cores
TARGET_GROWTH_MS = 0.02             # issue 37: the driver's serial growth per frame that allows it
PHASES = ("plan_s", "commit_s", "plan_cpu_s", "run_cpu_s", "commit_cpu_s", "rest_s", "rest_cpu_s")


def _median(runs: list[dict], key: str) -> float:
    return float(np.median([r[key] for r in runs]))


def size_row(runs: list[dict], scale: str) -> dict:
    """Medians of one adapter's runs at one corpus size: frames, units, the driver's phases, core s/frame."""
    row = {"scale": scale, "frames": int(runs[0]["frames"]), "units": int(runs[0]["units"]), "reps": len(runs)}
    row.update({k: float(np.median([r.get(k, 0.0) for r in runs])) for k in PHASES})
    row["serial_s"] = float(np.median([r["plan_s"] + r["commit_s"] for r in runs]))
    row["serial_cpu_s"] = float(np.median([r["plan_cpu_s"] + r["commit_cpu_s"] for r in runs]))
    # the pooled glove rest, bounded (module docstring): the serial work without it, and its cost per recording
    row["unbounded_s"] = float(np.median([r["plan_s"] + r["commit_s"] - r.get("rest_s", 0.0) for r in runs]))
    row["unbounded_cpu_s"] = float(np.median([r["plan_cpu_s"] + r["commit_cpu_s"] - r.get("rest_cpu_s", 0.0)
                                              for r in runs]))
    row["rest_recordings"] = int(runs[0].get("rest_recordings", 0))
    row["rest_gloves"] = int(runs[0].get("rest_gloves", 0))
    row["core_s_per_frame"] = float(np.median([r["worker_s"] / r["frames"] for r in runs]))
    row["core_cpu_s_per_frame"] = float(np.median([r["worker_cpu_s"] / r["frames"] for r in runs]))
    return row


def growth(small: dict, big: dict) -> dict:
    """Per frame growth (seconds per frame, slope between the sizes) and the fixed seconds, wall and CPU; the
    pooled glove rest (rest_s, rest_cpu_s: bounded, POOL_MAX recordings a glove) is left out of the slope and
    added to the fixed seconds at POOL_MAX recordings per glove the bigger size pooled."""
    span = big["frames"] - small["frames"]
    if span <= 0:
        raise ValueError(f"the driver bench needs two corpus sizes, got {small['frames']} and {big['frames']} frames")
    out = {}
    for name, key, rest in (("serial", "serial_s", "rest_s"), ("serial_cpu", "serial_cpu_s", "rest_cpu_s")):
        lo, hi = (row.get(key.replace("serial", "unbounded"), row[key]) for row in (small, big))
        slope = (hi - lo) / span
        pooled = big.get("rest_recordings", 0)
        rest_fixed = big.get(rest, 0.0) / pooled * POOL_MAX * big.get("rest_gloves", 1) if pooled else 0.0
        out[f"{name}_growth_s_per_frame"] = slope
        out[f"{name}_rest_fixed_s"] = rest_fixed
        out[f"{name}_fixed_s"] = lo - slope * small["frames"] + rest_fixed
    out["run_cpu_s_per_frame"] = big["run_cpu_s"] / big["frames"]   # overlaps the workers: an average is enough
    # the driver's work grows per episode (discovery, records), not per frame: per unit, and the frames a unit
    # (an episode) needs for the CPU growth to stay within the target
    units = big["units"] - small["units"]
    cpu = [row.get("unbounded_cpu_s", row["serial_cpu_s"]) for row in (small, big)]
    out["serial_cpu_growth_s_per_unit"] = (cpu[1] - cpu[0]) / units if units > 0 else 0.0
    out["frames_per_unit"] = big["frames"] / max(big["units"], 1)
    out["frames_per_unit_for_target"] = out["serial_cpu_growth_s_per_unit"] / (TARGET_GROWTH_MS / 1e3)
    return out


def project(row: dict, core_s_per_frame: float, frames: int = HT_BENCH_FRAMES, cores: int = CLUSTER_CORES,
            basis: str = "serial") -> dict:
    """`frames` on `cores` from a driver row (see the module docstring); `basis` "serial": wall seconds of
    the driver and the workers, as this machine gave them; "serial_cpu": CPU seconds of both (what a
    machine where nobody else runs would spend; pass the workers' CPU per frame then)."""
    serial = max(0.0, row[f"{basis}_fixed_s"]) + max(0.0, row[f"{basis}_growth_s_per_frame"]) * frames
    work = frames * core_s_per_frame / cores
    driver_run = row["run_cpu_s_per_frame"] * frames
    wall = serial + max(work, driver_run)
    return {"basis": basis, "frames": frames, "cores": cores, "core_hours": frames * core_s_per_frame / 3600.0,
            "serial_hours": serial / 3600.0, "wall_hours": wall / 3600.0,
            "speedup": (frames * core_s_per_frame + serial) / wall,
            "growth_ms_per_frame": 1e3 * row[f"{basis}_growth_s_per_frame"]}


def driver_rows(corpora: tuple[Path, Path], scales: tuple[str, str], work: Path, adapters: tuple[str, ...],
                workers: int, reps: int = 2, episode_frames: tuple[int, int] | None = None) -> dict:
    """Per adapter: `reps` ingests at `workers` of each corpus (alternated), the growth and the projections;
    `episode_frames`: the corpora's episode length (lo, hi) when set (said in the report), else None."""
    runs, summary = [], []
    for name in adapters:
        # warm-up, not counted: the first ingest of a process imports and caches (h5py, schemas, layouts,
        # the rasteriser), which would land on whichever size ran first
        ingest_run([(name, corpora[0] / name)], work / f"driver_{name}_warmup", workers)
        by_size: dict[str, list[dict]] = {scale: [] for scale in scales}
        for rep in range(reps):
            for corpus, scale in zip(corpora, scales):
                run = ingest_run([(name, corpus / name)], work / f"driver_{name}_{scale}", workers)
                run.update(rep=rep, scale=scale, adapter=name)
                runs.append(run)
                by_size[scale].append(run)
        small, big = (size_row(by_size[s], s) for s in scales)
        row = {"adapter": name, "workers": workers, "small": small, "big": big, **growth(small, big)}
        row["projection"] = project(row, big["core_s_per_frame"])
        row["projection_cpu"] = project(row, big["core_cpu_s_per_frame"], basis="serial_cpu")
        summary.append(row)
    return {"runs": runs, "summary": summary, "frames": HT_BENCH_FRAMES, "cores": CLUSTER_CORES,
            "target_speedup": TARGET_SPEEDUP, "target_growth_ms": TARGET_GROWTH_MS,
            "episode_frames": list(episode_frames) if episode_frames else None}


def driver_markdown(d: dict) -> list[str]:
    """REPORT.md lines of the driver section."""
    s0 = d["summary"][0]
    length = ("" if not d.get("episode_frames") else " written with episodes of {}-{} frames (`htdata sample "
              "--episode-frames`)".format(*d["episode_frames"]))
    lines = [f"Each adapter's part of the {s0['small']['scale']} and {s0['big']['scale']} sample corpora{length} at "
             f"{s0['workers']} workers, {s0['small']['reps']} rep(s) each (medians). serial = the driver's plan + "
             f"commit wall seconds; CPU = the driver process's own CPU in those phases; run CPU = its CPU while the "
             f"units run (per frame, big size; includes its idle polling). Growth = slope between the two sizes "
             f"(`htdata.benchmarks.driver`), the pooled glove rest (bounded: {POOL_MAX} recordings a glove) left "
             f"out of it and put in fixed s at that many recordings.", ""]
    rows = [{"adapter": s["adapter"], "frames": f"{s['small']['frames']} / {s['big']['frames']}",
             "units": f"{s['small']['units']} / {s['big']['units']}",
             "serial": f"{s['small']['serial_s']:.3g} / {s['big']['serial_s']:.3g}",
             "cpu": f"{s['small']['serial_cpu_s']:.3g} / {s['big']['serial_cpu_s']:.3g}",
             "rest": f"{s['small'].get('rest_cpu_s', 0.0):.3g} / {s['big'].get('rest_cpu_s', 0.0):.3g}",
             "growth": 1e3 * s["serial_growth_s_per_frame"], "growth_cpu": 1e3 * s["serial_cpu_growth_s_per_frame"],
             "run_cpu": 1e3 * s["run_cpu_s_per_frame"], "fixed": s["serial_fixed_s"],
             "per_unit": 1e3 * s["serial_cpu_growth_s_per_unit"], "fpu": s["frames_per_unit"],
             "fpu_needed": s["frames_per_unit_for_target"]}
            for s in d["summary"]]
    lines += table(rows, [("adapter", "adapter"), ("frames", "frames"), ("units", "units"),
                          ("serial", "serial s"), ("cpu", "serial CPU s"), ("rest", "of it rest CPU s"), ("growth", "growth ms/frame"),
                          ("growth_cpu", "growth CPU ms/frame"), ("run_cpu", "run CPU ms/frame"),
                          ("fixed", "fixed s"), ("per_unit", "growth CPU ms/unit"), ("fpu", "frames/unit"),
                          ("fpu_needed", f"frames/unit for <= {TARGET_GROWTH_MS} ms/frame")])
    for s in d["summary"]:
        g, c = 1e3 * s["serial_growth_s_per_frame"], 1e3 * s["serial_cpu_growth_s_per_frame"]
        lines.append(f"- {s['adapter']}: serial growth {g:.4f} ms/frame wall, {c:.4f} ms/frame CPU (target <= "
                     f"{d['target_growth_ms']} ms): {'met' if g <= d['target_growth_ms'] else 'MISSED'} / "
                     f"{'met' if c <= d['target_growth_ms'] else 'MISSED'}; the CPU growth is per unit (an "
                     f"episode): {1e3 * s['serial_cpu_growth_s_per_unit']:.2f} ms, within the target for episodes of "
                     f">= {s['frames_per_unit_for_target']:.0f} frames (the sample's: {s['frames_per_unit']:.0f}).")
    lines += ["", f"HT-Bench on paper: {d['frames']:,} frames of each source on {d['cores']} cores (serial = fixed + "
              f"growth x frames; work = frames x core s/frame (in-worker, {s0['workers']} workers) / cores; wall = "
              f"serial + max(work, run CPU x frames); storage bandwidth and Ray scheduling not modelled):", ""]
    proj = [{"adapter": s["adapter"], "basis": basis, "core_s": s["big"][core], **{k: s[p][k] for k in (
        "core_hours", "serial_hours", "wall_hours", "speedup")}}
        for s in d["summary"] for p, basis, core in (("projection", "wall", "core_s_per_frame"),
                                                       ("projection_cpu", "CPU", "core_cpu_s_per_frame"))]
    lines += table(proj, [("adapter", "source"), ("basis", "basis"), ("core_s", "core s/frame"),
                          ("core_hours", "core-hours"), ("serial_hours", "driver serial h"),
                          ("wall_hours", f"wall h on {d['cores']}"), ("speedup", "speed-up")])
    for s in d["summary"]:
        x, y = s["projection"]["speedup"], s["projection_cpu"]["speedup"]
        lines.append(f"- {s['adapter']}: {x:.1f}x (wall basis), {y:.1f}x (CPU basis) on {d['cores']} cores "
                     f"(target >= {d['target_speedup']:.0f}x): {'met' if x >= d['target_speedup'] else 'MISSED'} / "
                     f"{'met' if y >= d['target_speedup'] else 'MISSED'}.")
    return lines + [""]
