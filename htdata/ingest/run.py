"""Running an ingest: plan -> units (process pool, Ray or inline) -> report -> commit.

Failures (any exception inside an episode, every source file discovery
could not read, every episode whose layout does not resolve) are reported
with file/episode/frame in DATASET/reports/ingest.json, with every dropped
frame, every sync report and a per-stage timing breakdown of the units run.
Progress goes to `progress` (a tqdm bar on stderr when enabled): it advances
per finished episode (per finished unit with Ray).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from htdata.executors import make_executor
from htdata.format import INGEST_REPORT
from htdata.fsutil import write_bytes_atomic
from htdata.ingest.commit import commit
from htdata.ingest.plan import Source, UnitTask, check_settings_agree, discover_sources, plan_units
from htdata.ingest.timing import timing_summary
from htdata.ingest.unit import run_unit
from htdata.ingest.workdir import (clear_unit_files, directory_identity, dumps, load_valid_record, prepare_output,
                                   remove_strays)


class EpisodeProgress:
    """tqdm bar on stderr over episodes, with frames/s.

    Advanced by per-episode events from the workers (process pool, inline);
    when a unit's result arrives the bar is reconciled to the unit's true
    episode and frame counts, which covers executors that send no events
    (Ray), events that arrive late, and events repeated by a retried unit.
    """

    def __init__(self, tasks: list[UnitTask], done_units: set[int], enabled: bool):
        from tqdm import tqdm

        self.limits = {t.unit: len(t.episodes) for t in tasks}
        self.bar = tqdm(total=sum(self.limits.values()), unit="ep", file=sys.stderr, disable=not enabled,
                        desc="ingest")
        self.done = sum(self.limits[u] for u in done_units)   # episodes counted (a disabled bar keeps n = 0)
        self.bar.update(self.done)
        self.finished = set(done_units)
        self.episodes: dict[int, int] = {}
        self.unit_frames: dict[int, int] = {}
        self.frames = 0
        self.t0 = time.perf_counter()

    def _advance(self, episodes: int, frames: int) -> None:
        self.frames += frames
        if episodes:
            self.done += episodes
            self.bar.update(episodes)
        self.bar.set_postfix(frames_per_s=f"{self.frames / max(time.perf_counter() - self.t0, 1e-9):.1f}",
                             refresh=False)

    def event(self, event: dict) -> None:
        unit = int(event["unit"])
        if unit in self.finished or self.episodes.get(unit, 0) >= self.limits.get(unit, 0):
            return
        self.episodes[unit] = self.episodes.get(unit, 0) + 1
        self.unit_frames[unit] = self.unit_frames.get(unit, 0) + int(event.get("frames", 0))
        self._advance(1, int(event.get("frames", 0)))

    def unit_done(self, task: UnitTask, record: dict) -> None:
        self.finished.add(task.unit)
        episodes = self.limits[task.unit] - self.episodes.pop(task.unit, 0)
        frames = len(record["samples"]) - self.unit_frames.pop(task.unit, 0)
        self._advance(episodes, frames)

    def close(self) -> None:
        self.bar.close()


def ingest(sources: list[Source], out: Path, workers: int = 1, executor: str = "process",
           address: str | None = None, retries: int = 1, progress: bool = True,
           layout_dirs: tuple = ()) -> dict:
    """Run (or resume) an ingest; returns the report dict (also written to reports/ingest.json).

    `layout_dirs` are searched for layout ids before $HTDATA_LAYOUTS and the
    shipped layouts (`htdata ingest --layouts DIR`).
    """
    t_start = time.perf_counter()
    check_settings_agree(sources)
    prepare_output(out, directory_identity(sources))
    refs, plan_failures = discover_sources(sources, tuple(layout_dirs))
    tasks = plan_units(sources, refs, out)
    remove_strays(out, tasks)
    records, todo = {}, []
    for t in tasks:
        rec = load_valid_record(t)
        if rec is None:
            clear_unit_files(out, t.unit)
            todo.append(t)
        else:
            records[t.unit] = rec
    # Largest first: a long unit started last would leave the other workers idle at the end.
    todo.sort(key=lambda t: -t.est_frames)
    bar = EpisodeProgress(tasks, set(records), progress)
    t0 = time.perf_counter()
    try:
        runner = make_executor(executor, workers, address, retries)
        for task, rec in runner.map_units(run_unit, todo, on_progress=bar.event):
            records[task.unit] = rec
            bar.unit_done(task, rec)
    finally:
        bar.close()
    ordered = [records[t.unit] for t in tasks]
    report = {
        "pipelines": [s.pipeline.name for s in sources],
        "units": len(tasks), "units_run": len(todo), "units_resumed": len(tasks) - len(todo),
        "episodes_planned": sum(len(t.episodes) for t in tasks),
        "episodes_ingested": sum(len(r["episodes"]) for r in ordered),
        "samples": sum(len(r["samples"]) for r in ordered),
        "seconds": time.perf_counter() - t0,
        "failures": plan_failures + [f for r in ordered for f in r["failures"]],
        "dropped_frames": [d for r in ordered for d in r["dropped"]],
        "sync": {ep["episode_id"]: ep["sync"] for r in ordered for ep in r["episodes"]},
        "timing": timing_summary([records[t.unit] for t in todo], time.perf_counter() - t_start),
    }
    # Written before the commit too, so a run that commits nothing still explains why.
    write_bytes_atomic(out / INGEST_REPORT, dumps(report))
    if report["episodes_ingested"] == 0:
        raise ValueError(f"no episode could be ingested ({len(report['failures'])} failures); "
                         f"see {out / INGEST_REPORT}")
    commit(out, sources, ordered)
    report["timing"]["total_s"] = time.perf_counter() - t_start
    write_bytes_atomic(out / INGEST_REPORT, dumps(report))
    return report
