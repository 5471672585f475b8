"""Running an ingest: plan -> units (process pool, Ray or inline) -> report -> commit.

Failures (any exception inside an episode, every source file discovery
could not read, every episode whose layout does not resolve) are reported
with file/episode/frame in DATASET/reports/ingest.json, with every dropped
frame, every sync report, out-of-range raw value counts and hands not
ingested per episode, and a per-stage timing breakdown of the units run.
Progress goes to `progress` (a tqdm bar on stderr when enabled): it advances
per finished episode (per finished unit with Ray).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic
from htdata.format.table import INGEST_REPORT, MANIFEST_FILE, WORK_DIR
from htdata.glove.layouts import load_layout
from htdata.ingest.append import kept_unavailable, plan_append
from htdata.ingest.commit import check_compatible, commit
from htdata.ingest.executors import make_executor
from htdata.ingest.gloverest import identity_settings, pool_glove_rests, rest_notes, with_glove_rests
from htdata.ingest.plan import (
    Source,
    UnitTask,
    check_settings_agree,
    check_unique_ids,
    discover_sources,
    plan_units,
    resolve_sources,
)
from htdata.ingest.sourcesums import ChecksumLists, check_digests, plan_verification
from htdata.ingest.timing import timing_summary
from htdata.ingest.unit import run_unit
from htdata.ingest.workdir import (
    check_output,
    dumps,
    load_valid_record,
    prepare_output,
    remove_empty_output,
    remove_strays,
    unit_record_path,
)
from htdata.source.adapters import nothing_found
from htdata.source.adapters.sourcetree import RealPaths
from htdata.store.versions import restore_pointer
from htdata.write.newversion import NewVersion


class EpisodeProgress:
    """tqdm bar on stderr over episodes, with frames/s.

    Advanced by per-episode events from the workers (process pool, inline);
    when a unit's result arrives the bar is reconciled to the unit's true
    episode and frame counts, which covers executors that send no events
    (Ray), events that arrive late, and events repeated by a retried unit.

    Args:
        tasks: every work unit of the ingest.
        done_units: units already finished (a resumed ingest): counted from the start.
        enabled: draw the bar (False: count only, e.g. --quiet).
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
        frames = int(record["frames"]) - self.unit_frames.pop(task.unit, 0)
        self._advance(episodes, frames)

    def close(self) -> None:
        self.bar.close()


def ingest(sources: list[Source], out: Path, workers: int = 1, executor: str = "process",
           address: str | None = None, retries: int = 1, progress: bool = True,
           layout_dirs: tuple = (), command: str = "htdata ingest", verify_sources: bool = False) -> dict:
    """Ingest (or resume, or append to) the dataset at `out`; returns the report (also reports/ingest.json).

    Holds the dataset's writer lock throughout. Source files of the episodes to ingest are
    hashed by the units that read them and checked here against checksum lists
    (htdata/ingest/sourcesums.py): the driver reads no source byte.

    Args:
        sources: the recordings to ingest, each a folder with the pipeline that reads it (`Source`).
        out: the dataset folder: new (created), a dataset to append to, or an ingest to resume.
        workers: worker processes of the "process" executor, a local Ray's CPUs with "ray" (htdata/workers.py:
            None = every usable core; 0 = inline, in this process, "process" only).
        executor: "process" or "ray" (htdata/ingest/executors.py).
        address: the Ray cluster to join (executor "ray" only).
        retries: how often a failed work unit is run again before it counts as failed.
        progress: show a progress bar on stderr.
        layout_dirs: folders searched for layout ids before $HTDATA_LAYOUTS and the shipped layouts (`--layouts`).
        command: the command line recorded in the lock and the new version.
        verify_sources: refuse a source file whose sha256 differs from its SHA256SUMS line, or is not listed.

    Returns:
        The ingest report (episodes ingested, failures, notes, timing, the committed version).

    Raises:
        ConfigError / ArgumentError (ValueErrors): pipelines or settings that disagree (with each other or with
            the dataset), an `out` that is not a dataset, a source folder with no recording, or no episode
            ingested into a new dataset.
        Any error a source-wide discovery raises, its type kept (plan.discover_sources).
        DatasetLocked: another writer holds the dataset.
    """
    t_start, cpu_start = time.perf_counter(), time.process_time()
    check_settings_agree(sources)
    check_output(out)
    existed = out.exists()
    new = not existed or not any(out.iterdir())
    try:
        # the lock, the parent and unit numbers; resumable: finished units stay for a re-run to resume
        with NewVersion(out, command, parent="optional", resumable=True) as nv:
            try:
                return _ingest(sources, nv, workers, executor, address, retries, progress, layout_dirs,
                               verify_sources, t_start, cpu_start)
            except BaseException:
                if new:   # a first ingest that failed before writing anything leaves no empty skeleton
                    remove_empty_output(out)      # (under the lock: no other writer's folders)
                raise
    except BaseException:
        if new and not existed:   # the lock released (or never ours): `out` itself, when nothing is in it
            remove_empty_output(out, subfolders=False)
        raise


def _ingest(sources, nv: NewVersion, workers, executor, address, retries, progress, layout_dirs,
            verify_sources, t_start, cpu_start) -> dict:
    """`ingest` in its new-version transaction (writer lock, parent): the executor started, plan, units,
    report, commit."""
    out, parent = nv.root, nv.parent
    with _started_executor(executor, workers, address, retries) as runner:
        prepare_output(out)
        refs, plan_failures = discover_sources(sources, tuple(layout_dirs))
        check_found_something(sources, refs, plan_failures)
        check_unique_ids(refs)
        # the codec rule needs the run's gloves: resolved after discovery, before anything is fingerprinted
        sources = resolve_sources(sources, refs, parent.manifest["codec"]["tactile"] if parent else None)
        sources = [dataclasses.replace(s, pipeline=s.pipeline.with_maps(s.pipeline.tactile.maps.resolved(
            parent.manifest if parent else None))) for s in sources]
        check_compatible(parent, sources)
        # pipeline (CLI) order, then episode id: the order units are numbered in
        pairs = [(r, s) for s, rs in zip(sources, refs) for r in sorted(rs, key=lambda r: r.episode_id)]
        # a raw-count glove without a [normalise] table: its rest pooled over this run's recordings of it
        t_rest, cpu_rest = time.perf_counter(), time.process_time()    # bounded: POOL_MAX recordings a glove
        rests = pool_glove_rests(pairs, out, parent, _progress_line if progress else None)
        rest_timing = {"rest_s": time.perf_counter() - t_rest, "rest_cpu_s": time.process_time() - cpu_rest,
                       "rest_recordings": sum(r.recordings for r in rests.values()),
                       "rest_gloves": sum(1 for r in rests.values() if r.recordings)}
        if rests:
            sources = with_glove_rests(sources, rests, pairs)
            pairs = [(r, s) for s, rs in zip(sources, refs) for r in sorted(rs, key=lambda r: r.episode_id)]
        settings = {id(s): identity_settings(s.pipeline) for s in sources}
        plan = plan_append(parent, [r for r, _ in pairs], [settings[id(s)] for _, s in pairs])
        source_of = {r.episode_id: s for r, s in pairs}
        lists, real = ChecksumLists(), RealPaths()
        checked = plan_verification(plan.todo, {r.episode_id: source_of[r.episode_id].root for r in plan.todo},
                                    verify_sources, lists, real)
        plan.todo = checked.refs
        plan_failures = plan_failures + checked.failures
        tasks = plan_units([(r, source_of[r.episode_id]) for r in plan.todo], out, nv.first_unit, real)
        remove_strays(out, tasks, nv.first_unit)
        t_run, cpu_run = time.perf_counter(), time.process_time()
        records, ran = run_units(tasks, out, runner, progress)
        t_ran, cpu_ran = time.perf_counter(), time.process_time()
        # the digests the units computed, checked against the lists; source_sha256 into the records
        sum_notes = check_digests(tasks, records, verify_sources, lists, real)
        report = build_report(sources, tasks, records, ran, plan_failures, plan, parent,
                              discovered={r.episode_id for rs in refs for r in rs}, t_start=t_start)
        report["notes"] += checked.notes + sum_notes
        report["notes"] += raw_count_default_notes([(r, source_of[r.episode_id]) for r in plan.todo])
        report["notes"] += rest_notes(sources, rests)
        if nv.note:
            report["notes"].append(nv.note)
        write_bytes_atomic(out / INGEST_REPORT, dumps(report))   # explains a run that commits nothing too
        if parent is None:
            check_ingested_something(report, out)
        report["timing"].update(rest_timing, plan_s=t_run - t_start, run_s=t_ran - t_run,
                                plan_cpu_s=cpu_run - cpu_start, run_cpu_s=cpu_ran - cpu_run)
        report["version"] = _commit_or_keep(nv, sources, records, plan, report)
    report["timing"]["total_s"] = time.perf_counter() - t_start
    report["timing"]["commit_s"] = report["timing"]["total_s"] - (t_ran - t_start)
    # the driver's own CPU (this process, not its workers) per phase: what a cluster cannot parallelise
    report["timing"]["commit_cpu_s"] = time.process_time() - cpu_ran
    write_bytes_atomic(out / INGEST_REPORT, dumps(report))
    return report


def _progress_line(text: str) -> None:
    print(f"htdata ingest: {text}", file=sys.stderr, flush=True)


def raw_count_default_notes(pairs: list[tuple]) -> list[str]:
    """One note per raw-count layout without a `[normalise.<id>]` table among the (ref, source) pairs ingested
    now: which default normalisation it got."""
    notes = []
    for ref, source in pairs:
        normalising = source.pipeline.normalise_settings()     # one per pipeline: each layout resolved once
        for path in sorted(set(ref.layout_files.values())):
            line = normalising.default_note(load_layout(path))
            if line and line not in notes:
                notes.append(line)
    return notes


def check_ingested_something(report: dict, out: Path) -> None:
    """A new dataset into which no episode could be ingested is an error naming the first failures."""
    if report["episodes_ingested"] == 0:
        shown = "; ".join(failure_line(f) for f in report["failures"][:3])
        more = f"; ... {len(report['failures']) - 3} more" if len(report["failures"]) > 3 else ""
        raise ArgumentError(f"no episode could be ingested ({len(report['failures'])} failures); see "
                            f"{out / INGEST_REPORT}: {shown}{more}")


def _commit_or_keep(nv: NewVersion, sources, records: list[dict], plan, report: dict):
    """Commit a new version when episodes were ingested or relabelled, else keep the parent (its pointer
    restored when lost or stale, noted in the report); returns the version now current."""
    if report["episodes_ingested"] or plan.relabelled:
        return commit(nv, sources, records, plan)["version"]
    parent, notes = nv.parent, report["notes"]
    notes.append(f"nothing changed: version {parent.version} stays current")
    if parent.version is not None and restore_pointer(nv.root, parent.version):   # a lost or stale pointer
        notes.append(f"{MANIFEST_FILE} rewritten from version {parent.version}'s file")
    return parent.version


@contextmanager
def _started_executor(kind: str, workers: int, address: str | None, retries: int):
    """The unit executor, its workers spawned and importing the unit code while the driver plans."""
    runner = make_executor(kind, workers, address, retries)
    runner.start(preload=(run_unit.__module__,))
    try:
        yield runner
    finally:
        runner.close()


def check_found_something(sources, refs: list[list], failures: list[dict]) -> None:
    """A source folder in which the adapter found no recording at all (not even a bad one) is an error:
    a wrong path or pipeline, not "nothing changed"."""
    for source, found in zip(sources, refs):
        root = str(source.root).rstrip("/") + "/"
        if not found and not any(str(f.get("file") or f.get("source_ref") or "").startswith(root) for f in failures):
            raise ArgumentError(f"{nothing_found(source.pipeline.adapter.name, source.root)} (pipeline "
                                f"{source.pipeline.name!r}); check the folder and the pipeline")


def run_units(tasks: list[UnitTask], out: Path, runner, progress: bool) -> tuple[list[dict], list[dict]]:
    """Resume finished units, run the rest (largest first); returns (records in unit order, records run now)."""
    records, todo = {}, []
    present = {p.name for p in (out / WORK_DIR).iterdir()}   # one listing, not a look-up per unit
    for t in tasks:
        # a unit to run clears its own leftovers where it runs (unit.run_unit): nothing to delete here
        rec = load_valid_record(t) if unit_record_path(out, t.unit).name in present else None
        if rec is None:
            todo.append(t)
        else:
            records[t.unit] = rec
    # Largest first: a long unit started last would leave the other workers idle at the end.
    todo.sort(key=lambda t: -t.est_frames)
    bar = EpisodeProgress(tasks, set(records), progress)
    try:
        if todo:
            for task, rec in runner.map_units(run_unit, todo, on_progress=bar.event):
                records[task.unit] = rec
                bar.unit_done(task, rec)
    finally:
        bar.close()
    return [records[t.unit] for t in tasks], [records[t.unit] for t in todo]


def failure_line(f: dict) -> str:
    """"FILE [episode] frame N: error" for a report failure (stderr)."""
    episode = f" [{f['episode_id']}]" if f["episode_id"] is not None else ""
    frame = f" frame {f['frame']}" if f["frame"] is not None else ""
    return f"{f['file']}{episode}{frame}: {f['error']}"


def build_report(sources, tasks, ordered, ran, plan_failures, plan, parent, discovered, t_start) -> dict:
    """reports/ingest.json: counts, failures, what was kept/reused/replaced, sync reports, timing."""
    failures = plan_failures + [f for r in ordered for f in r["failures"]]
    failed_replacements = sorted({f["episode_id"] for f in failures} & plan.replaced)
    kept = kept_unavailable(parent, discovered, [s.root for s in sources])
    notes = [f"source unavailable: {e} kept from version {parent.version}" for e in kept]
    notes += [f"re-ingest failed: {e} kept from version {parent.version}" for e in failed_replacements]
    raw_dropped = {ep["episode_id"]: ep["raw_rows_dropped"] for r in ordered for ep in r["episodes"]
                   if ep.get("raw_rows_dropped")}
    # what the console must say, not only the report: hands left out, raw values outside the layout range
    notes += [f"{ep['episode_id']}: {hand} hand not ingested: {why}" for r in ordered for ep in r["episodes"]
              for hand, why in sorted(ep.get("hands_excluded", {}).items())]
    notes += [f"{ep['episode_id']}: {hand} hand: {c['frames']} frames hold raw values outside the layout range "
              f"({c['below']} below, {c['above']} above; pipeline [normalise] out_of_range decides)"
              for r in ordered for ep in r["episodes"] for hand, c in sorted(ep.get("out_of_range", {}).items())]
    notes += [f"{e}: {n} {h} glove rows far from every video frame dropped (no sample stores them)"
              for e, d in sorted(raw_dropped.items()) for h, n in sorted(d.items())]
    return {
        "pipelines": [s.pipeline.name for s in sources],
        "parent_version": parent.version if parent else None,
        "units": len(tasks), "units_run": len(ran), "units_resumed": len(tasks) - len(ran),
        "episodes_planned": len(tasks),
        "episodes_ingested": sum(len(r["episodes"]) for r in ordered),
        "samples": sum(int(r["frames"]) for r in ordered),
        # samples without tactile (RGB frames the pairing could not use), by reason; tactile-only episodes
        "rgb_only_samples": _counts(ep.get("rgb_only_frames", {}) for r in ordered for ep in r["episodes"]),
        "tactile_only_episodes": sorted(ep["episode_id"] for r in ordered for ep in r["episodes"]
                                        if ep.get("tactile_only")),
        "episodes_unchanged": len(plan.reused), "episodes_relabelled": sorted(plan.relabelled),
        "episodes_replaced": sorted(plan.replaced - set(failed_replacements)),
        "episodes_kept_unavailable": kept, "notes": notes,
        "seconds": time.perf_counter() - t_start,
        "failures": failures,
        "dropped_frames": [d for r in ordered for d in r["dropped"]],
        "sync": {ep["episode_id"]: ep["sync"] for r in ordered for ep in r["episodes"]},
        # raw values outside the layout range and hands not ingested, per episode (only episodes that have any)
        "out_of_range": {ep["episode_id"]: ep["out_of_range"] for r in ordered for ep in r["episodes"]
                         if ep.get("out_of_range")},
        "hands_excluded": {ep["episode_id"]: ep["hands_excluded"] for r in ordered for ep in r["episodes"]
                           if ep.get("hands_excluded")},
        "raw_rows_dropped": raw_dropped,
        "raw_rows_capped": {ep["episode_id"]: ep["raw_rows_capped"] for r in ordered for ep in r["episodes"]
                            if ep.get("raw_rows_capped")},
        # cells outside every block whose raw values move (htdata/glove/activity.py), per episode and hand
        "unmapped_moving": {ep["episode_id"]: {h: {**e, "layout": ep["layouts"][h]} for h, e in ep["unmapped_moving"].items()}
                            for r in ordered for ep in r["episodes"] if ep.get("unmapped_moving")},
        # the episode records' warnings (e.g. raw values out of range, clipped): the CLI prints them on stderr
        "episode_warnings": {eid: w for eid, w in ((ep["episode_id"], _episode_warnings(ep))
                                                     for r in ordered for ep in r["episodes"]) if w},
        "timing": timing_summary(ran, time.perf_counter() - t_start),
    }


def _episode_warnings(ep: dict) -> list[str]:
    """An episode record's warnings for stderr: its "warning:" notes and its clock's (reordered, duplicate,
    stuck timestamps: htdata/source/sync.py), each once."""
    notes = [n for n in ep.get("notes", []) if n.startswith("warning:")]
    return list(dict.fromkeys(notes + list((ep.get("sync") or {}).get("warnings", []))))


def _counts(dicts) -> dict[str, int]:
    total: dict[str, int] = {}
    for d in dicts:
        for k, v in d.items():
            total[k] = total.get(k, 0) + int(v)
    return dict(sorted(total.items()))
