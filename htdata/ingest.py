"""`htdata ingest`: raw recordings -> a committed, sharded dataset.

    htdata ingest --pipeline pipelines/opentouch.toml /raw/opentouch OUT
    htdata ingest --pipeline pipelines/opentouch.toml=/raw/opentouch \\
                  --pipeline pipelines/touchanything.toml=/raw/touchanything OUT
    htdata ingest --pipeline A.toml --pipeline B.toml SRC_A SRC_B OUT

Plan: every pipeline's adapter discovers its episodes (sorted by id); in
pipeline order, episodes are packed into work units of >= samples_per_shard
/ UNITS_PER_SHARD estimated frames (a long episode is a unit of its own and
spans several shards). Unit numbers are therefore fixed by the sorted
episode lists and the pipeline config, never by --workers, so a run resumed
with another worker count finds the same units. Small units (a quarter
shard: 64 frames by default) give a pool enough units to balance on small
corpora; units run largest first.

A unit (`run_unit`, in a worker process or a Ray task) opens each episode,
cleans and pairs timestamps (sync.py), reads tactile rows in chunks,
normalises, drops frames with non-finite live taxels (counted), rasterises,
encodes EXR/JPEG and spools the episode's samples to a temp file; only a
fully successful episode is copied into the unit's shards, so a bad episode
never leaves half its frames behind. Memory stays flat in episode length.

Crash safety and resume: a finished unit writes DATASET/.work/unit-UUUUUU.json
atomically (its records, its fingerprint = pipeline + episode ids + source
fingerprints, its shards' sha256). A re-run skips units whose record,
fingerprint and shards (sha256) all match, removes temp files and rewrites
every other unit from scratch. dataset.json is removed at start and written
LAST by `commit_dataset`, so a crashed run is never mistaken for a dataset.

Failures (EpisodeError or any exception inside an episode, and every source
file discovery could not read) are reported with file/episode/frame in
DATASET/reports/ingest.json (with every dropped frame, every sync report and
a per-stage timing breakdown of the units run); the exit code is 1 unless
--allow-failures. The progress bar (stderr) advances per finished episode
(per finished unit with Ray).

Test hooks (fault injection, used by tests/test_ingest.py):
HTDATA_TEST_FAULT_UNIT=U and HTDATA_TEST_FAULT=crash|hang make unit U
`os._exit(137)` or sleep forever right after its first episode reached the
shard writer (a temp shard exists, no unit record yet).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import io
import json
import os
import pickle
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.codec import DEFAULT_CODEC_INFO, encode_rgb, encode_tactile
from htdata.errors import EpisodeError
from htdata.fsutil import sha256_file, write_bytes_atomic
from htdata.executors import UnitFailed, make_executor, report_progress
from htdata.normalise import Normaliser
from htdata.pipeline import PipelineConfig, load_pipeline
from htdata.rgb import to_square_224
from htdata.shardio import SampleRecord, ShardRecord, ShardWriter, sample_key
from htdata.sync import pair

HANDS = ("left", "right")
WORK_DIR = ".work"
SHARDS_DIR = "shards"
REPORT_FILE = "reports/ingest.json"
STATE_FILE = "ingest.json"          # under .work: which pipelines this directory belongs to
MANIFEST_FILE = "dataset.json"


# --------------------------------------------------------------------------- small helpers



def dumps(obj) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode()




def get_adapter(name: str):
    """The adapter registered under `name` (htdata/adapters/__init__.py)."""
    from htdata.adapters import get_adapter as registry_lookup

    return registry_lookup(name)


# --------------------------------------------------------------------------- stage timing

STAGES = ("decode", "resize", "normalise", "rasterise", "encode", "write")


class StageClock:
    """Wall seconds per ingest stage, summed over a unit (perf_counter around whole calls).

    decode = opening the episode's streams + RGB decode + tactile reads;
    resize = rgb.to_square_224; normalise; rasterise (incl. bend vectors and
    contact stats); encode = EXR + JPEG (+ bend .npy, sample JSON); write =
    spool writes + replay into the shard writer + closing shards.
    """

    def __init__(self):
        self.seconds = dict.fromkeys(STAGES, 0.0)

    @contextmanager
    def stage(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - t0

    def as_record(self) -> dict:
        return {f"{k}_s": v for k, v in self.seconds.items()}


def timing_summary(records: list[dict], total_s: float) -> dict:
    """report["timing"] from the records of the units run in this invocation."""
    worker_s = sum(float(r.get("seconds", 0.0)) for r in records)
    out = {"frames": sum(len(r["samples"]) for r in records), "total_s": total_s, "worker_s": worker_s}
    staged = 0.0
    for name in STAGES:
        v = sum(float(r.get("timing", {}).get(f"{name}_s", 0.0)) for r in records)
        out[f"{name}_s"] = v
        staged += v
    out["other_s"] = max(worker_s - staged, 0.0)
    return out


# --------------------------------------------------------------------------- planning

@dataclass
class Source:
    pipeline: PipelineConfig
    root: Path


@dataclass
class UnitTask:
    """One work unit: picklable, small (episode refs only)."""
    unit: int
    out: str
    pipeline: dict          # PipelineConfig.to_dict()
    pipeline_path: str
    root: str
    episodes: list          # list[EpisodeRef]

    @property
    def est_frames(self) -> int:
        return sum(int(r.est_frames) for r in self.episodes)

    def fingerprint(self) -> str:
        """Changes when the pipeline, the episode list or any source file changes."""
        ident = {"pipeline": self.pipeline,
                 "episodes": [[r.episode_id, r.source_ref, r.fingerprint] for r in self.episodes]}
        return hashlib.sha1(json.dumps(ident, sort_keys=True).encode()).hexdigest()

    def __repr__(self) -> str:
        return f"unit {self.unit:06d} ({len(self.episodes)} episodes)"


# Units per shard's worth of frames: the unit target is samples_per_shard / 4.
UNITS_PER_SHARD = 4


def unit_target_frames(samples_per_shard: int) -> int:
    """Estimated frames a work unit is packed up to (from the pipeline config only)."""
    return max(1, -(-int(samples_per_shard) // UNITS_PER_SHARD))


def pack_units(episode_frames: list[int], target_frames: int) -> list[list[int]]:
    """Group consecutive episodes (by position) into units of >= target_frames est. frames."""
    units, current, total = [], [], 0
    for i, n in enumerate(episode_frames):
        current.append(i)
        total += max(int(n), 0)
        if total >= target_frames:
            units.append(current)
            current, total = [], 0
    if current:
        units.append(current)
    return units


def plan_units(sources: list[Source], refs_per_source: list[list], out: Path) -> list[UnitTask]:
    seen: dict[str, str] = {}
    tasks: list[UnitTask] = []
    for src, refs in zip(sources, refs_per_source):
        refs = sorted(refs, key=lambda r: r.episode_id)
        for r in refs:
            if r.episode_id in seen:
                raise ValueError(f"episode id {r.episode_id!r} found twice: {seen[r.episode_id]} and {r.source_ref}")
            seen[r.episode_id] = r.source_ref
        target = unit_target_frames(src.pipeline.shards.samples_per_shard)
        for group in pack_units([r.est_frames for r in refs], target):
            tasks.append(UnitTask(unit=len(tasks), out=str(out), pipeline=src.pipeline.to_dict(),
                                  pipeline_path=src.pipeline.path, root=str(src.root),
                                  episodes=[refs[i] for i in group]))
    return tasks


# --------------------------------------------------------------------------- one episode

class Caches:
    """Layouts and rasterisers are built once per worker process."""

    def __init__(self):
        self._layouts, self._rasters = {}, {}

    def layout(self, layout_id: str):
        if layout_id not in self._layouts:
            from htdata.layouts import load_layout
            self._layouts[layout_id] = load_layout(layout_id)
        return self._layouts[layout_id]

    def rasteriser(self, layout_id: str, mode: str):
        key = (layout_id, mode)
        if key not in self._rasters:
            from htdata.rasterise import Rasteriser
            self._rasters[key] = Rasteriser(self.layout(layout_id), mode=mode)
        return self._rasters[key]


_CACHES = Caches()


class RgbFetcher:
    """Hand out RGB frames by index while reading the video once, in file order.

    Frames wanted later (only when timestamps were out of file order) wait as
    224x224 arrays; unwanted frames are skipped without resizing.
    """

    def __init__(self, ref, frames, wanted: np.ndarray, resize, clock: StageClock):
        self.ref = ref
        self.frames = iter(frames)
        self.wanted = set(int(i) for i in wanted)
        self.resize = resize
        self.clock = clock
        self.pending: dict[int, np.ndarray] = {}

    def get(self, index: int) -> np.ndarray:
        index = int(index)
        while index not in self.pending:
            try:
                with self.clock.stage("decode"):
                    i, frame = next(self.frames)
            except StopIteration:
                raise EpisodeError(self.ref, index, "RGB stream ended before this frame") from None
            i = int(i)
            if i in self.wanted:
                with self.clock.stage("resize"):
                    self.pending[i] = self.resize(frame, i)
        self.wanted.discard(index)
        return self.pending.pop(index)

    def discard(self, index: int) -> None:
        self.wanted.discard(int(index))
        self.pending.pop(int(index), None)


class Spool:
    """Encoded samples of the current episode on disk (flat memory), replayed on success."""

    def __init__(self, path: Path):
        self.path = path
        self.f = None
        self.count = 0

    def start(self) -> None:
        self.close()
        self.f = open(self.path, "w+b")
        self.count = 0

    def add(self, key: str, members: dict[str, bytes]) -> None:
        pickle.dump((key, members), self.f, protocol=pickle.HIGHEST_PROTOCOL)
        self.count += 1

    def replay(self):
        self.f.flush()
        self.f.seek(0)
        for _ in range(self.count):
            yield pickle.load(self.f)

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None
        self.path.unlink(missing_ok=True)


@dataclass
class EpisodeOutcome:
    record: dict
    dropped: list = field(default_factory=list)   # [(rgb index, reason)]


def _fps(rgb_ts: np.ndarray) -> float | None:
    d = np.diff(np.unique(np.asarray(rgb_ts, dtype=np.int64)))
    return float(1e9 / np.median(d)) if d.size else None


def ingest_episode(ref, cfg: PipelineConfig, adapter, spool: Spool, where: dict,
                   clock: StageClock | None = None) -> EpisodeOutcome:
    """Stream one episode into `spool`; raise on any failure. `where["frame"]` tracks progress,
    `clock` collects the time spent per stage."""
    clock = clock or StageClock()
    params = cfg.adapter.params
    hands = [h for h in HANDS if h in ref.hands]
    layouts = {h: _CACHES.layout(cfg.layout_for(h, ref.layouts[h])) for h in hands}
    with clock.stage("decode"):
        opened = adapter.open(ref, params)
    with opened as streams:
        missing = [h for h in hands if h not in streams.tactile_timestamps_ns]
        if missing:
            raise EpisodeError(ref, None, f"no tactile stream for hand(s) {missing}")
        try:
            sync = pair(streams.rgb_timestamps_ns, {h: streams.tactile_timestamps_ns[h] for h in hands},
                        cfg.sync.max_skew_ns, cfg.sync.policy)
        except ValueError as e:
            raise EpisodeError(ref, None, f"sync: {e}") from e
        K = int(sync.rgb_index.size)
        if K == 0:
            raise EpisodeError(ref, None, f"no RGB frame has tactile data within {cfg.sync.max_skew_ms} ms "
                               f"({sync.report['drop_reasons']})")
        normalisers = {h: Normaliser(cfg.normalise_for(layouts[h]), layouts[h]) for h in hands}
        rasters = {h: _CACHES.rasteriser(layouts[h].layout_id, cfg.tactile.raster_mode) for h in hands}
        keep_bend = {h: cfg.tactile.keep_bend and len(layouts[h].bend_cells) > 0 for h in hands}
        rgb_cfg = cfg.rgb

        def resize(frame, i):
            return to_square_224(frame, rgb_cfg.size, rgb_cfg.crop, rgb_cfg.interpolation,
                                 where=f"{ref.source_ref} [{ref.episode_id}] frame {i}")

        fetcher = RgbFetcher(ref, streams.iter_rgb(), sync.rgb_index, resize, clock)
        dropped: list[tuple[int, str]] = list(sync.dropped)
        contact_sum = {h: 0.0 for h in hands}
        contact_max = {h: 0.0 for h in hands}
        live_count = {h: int(layouts[h].live_mask.sum()) for h in hands}
        hands_flags = {h: h in hands for h in HANDS}
        n_out = 0
        spool.start()
        chunk = cfg.tactile.chunk_frames
        for start in range(0, K, chunk):
            stop = min(K, start + chunk)
            rgb_idx = sync.rgb_index[start:stop]
            where["frame"] = int(rgb_idx[0])
            ok = np.ones(stop - start, dtype=bool)
            values = {}
            for h in hands:
                tidx = sync.tactile_index[h][start:stop]
                uniq, inverse = np.unique(tidx, return_inverse=True)  # adapters want increasing indices
                with clock.stage("decode"):
                    raw = np.asarray(streams.read_tactile(h, uniq))
                if raw.ndim != 3 or raw.shape[1:] != tuple(layouts[h].grid) or raw.shape[0] != uniq.size:
                    raise EpisodeError(ref, int(rgb_idx[0]), f"{h} tactile rows have shape {raw.shape}, expected "
                                       f"({uniq.size}, {layouts[h].grid[0]}, {layouts[h].grid[1]}) for layout "
                                       f"{layouts[h].layout_id}")
                raw = raw[inverse.reshape(-1)]
                with clock.stage("normalise"):
                    if start == 0:
                        normalisers[h].fit_baseline(raw)
                    v, finite = normalisers[h].apply(raw)
                for j in np.flatnonzero(ok & ~finite):
                    dropped.append((int(rgb_idx[j]), f"nonfinite_tactile:{h}"))
                ok &= finite
                values[h] = v
            for j in np.flatnonzero(~ok):
                fetcher.discard(rgb_idx[j])
            keep = np.flatnonzero(ok)
            if keep.size == 0:
                continue
            maps, bends = {}, {}
            with clock.stage("rasterise"):
                for h in hands:
                    v = values[h][keep]
                    maps[h] = rasters[h].render(v)
                    live = v[:, layouts[h].live_mask]
                    contact_sum[h] += float(live.sum(dtype=np.float64))
                    contact_max[h] = max(contact_max[h], float(live.max(initial=0.0)))
                    if keep_bend[h]:
                        bends[h] = rasters[h].bend_vector(v)
            for n, j in enumerate(keep):
                i = int(rgb_idx[j])
                where["frame"] = i
                key = sample_key(ref.episode_id, n_out)
                k = start + int(j)
                rgb = fetcher.get(i)  # timed inside as decode + resize
                with clock.stage("encode"):
                    meta = {"key": key, "episode_id": ref.episode_id, "frame_index": n_out,
                            "source_frame": i, "t_rgb_ns": int(sync.t_rgb_ns[k]),
                            "t_tactile_ns": {h: int(sync.t_tactile_ns[h][k]) for h in hands},
                            "sync_offset_ns": {h: int(sync.skew_ns[h][k]) for h in hands},
                            "hands": hands_flags}
                    members = {"json": json.dumps(meta, sort_keys=True, separators=(",", ":")).encode(),
                               "rgb.jpg": encode_rgb(rgb, rgb_cfg.quality, where=key)}
                    for h in hands:
                        members[f"tactile_{h}.exr"] = encode_tactile(maps[h][n], cfg.tactile.compression,
                                                                     where=f"{key} ({h})")
                    for h, b in bends.items():
                        buf = io.BytesIO()
                        np.save(buf, b[n], allow_pickle=False)
                        members[f"bend_{h}.npy"] = buf.getvalue()
                with clock.stage("write"):
                    spool.add(key, members)
                n_out += 1
        if n_out == 0:
            raise EpisodeError(ref, None, f"no frame left: all {K} synchronised frames had non-finite tactile values")
        notes = list(streams.notes) + list(sync.report.get("warnings", []))
        fps = _fps(streams.rgb_timestamps_ns)
        if fps is None:
            fps = float(ref.extra.get("fps", 30.0)) if isinstance(ref.extra, dict) else 30.0
            notes.append(f"fps unknown (single RGB timestamp): recorded as {fps}")
    reasons: dict[str, int] = {}
    for _, r in dropped:
        reasons[r] = reasons.get(r, 0) + 1
    record = {
        "episode_id": ref.episode_id, "source": ref.source, "source_ref": ref.source_ref,
        "task": ref.task, "scene": ref.scene, "hands": hands,
        "layouts": {h: layouts[h].layout_id for h in hands},
        "num_frames": n_out, "fps": fps,
        "stats": {"mean_contact": {h: contact_sum[h] / (n_out * live_count[h]) for h in hands},
                  "max_contact": contact_max, "frames_in": int(sync.report["n_rgb"]),
                  "frames_kept": n_out, "frames_dropped": len(dropped)},
        "sync": sync.report, "dropped_frames": reasons, "notes": notes,
    }
    if isinstance(ref.extra, dict) and ref.extra.get("source_split"):
        record["source_split"] = str(ref.extra["source_split"])
    return EpisodeOutcome(record=record, dropped=sorted(dropped))


# --------------------------------------------------------------------------- one unit

def unit_record_path(out: Path, unit: int) -> Path:
    return out / WORK_DIR / f"unit-{unit:06d}.json"


def clear_unit_files(out: Path, unit: int) -> None:
    """Remove everything a (crashed or stale) run of this unit left behind."""
    unit_record_path(out, unit).unlink(missing_ok=True)
    for p in (out / SHARDS_DIR).glob(f"shard-{unit:06d}-*.tar"):
        p.unlink()
    for p in (out / SHARDS_DIR).glob(f".shard-{unit:06d}-*.tar.tmp"):
        p.unlink()
    (out / WORK_DIR / f"spool-{unit:06d}.bin").unlink(missing_ok=True)


def _fault_hook(unit: int) -> None:
    if os.environ.get("HTDATA_TEST_FAULT_UNIT") != str(unit):
        return
    mode = os.environ.get("HTDATA_TEST_FAULT", "crash")
    if mode == "hang":
        while True:
            time.sleep(3600)
    os._exit(137)


def failure_entry(ref, exc: BaseException, frame: int | None) -> dict:
    if isinstance(exc, EpisodeError):
        file, frame, msg = exc.file, exc.frame if exc.frame is not None else frame, exc.message
    else:
        file, msg = str(ref.source_ref).split("::", 1)[0], f"{type(exc).__name__}: {exc}"
    return {"stage": "ingest", "episode_id": ref.episode_id, "source": ref.source, "source_ref": ref.source_ref,
            "file": file, "frame": frame, "error": msg}


def discovery_failure_entry(source: str, exc: EpisodeError) -> dict:
    """A file (or one of its episodes) that discovery could not read; episode_id may be None."""
    return {"stage": "discovery", "episode_id": exc.episode_id, "source": source, "source_ref": exc.file,
            "file": exc.file, "frame": exc.frame, "error": exc.message}


def run_unit(task: UnitTask) -> dict:
    """Ingest one unit; write its shards and its done record; return the (small) record."""
    out = Path(task.out)
    clear_unit_files(out, task.unit)  # idempotent: a retried unit starts clean
    cfg = PipelineConfig.from_dict(task.pipeline, where=task.pipeline_path or task.pipeline["name"])
    adapter = get_adapter(cfg.adapter.name)
    spool = Spool(out / WORK_DIR / f"spool-{task.unit:06d}.bin")
    episodes, failures, dropped = [], [], []
    clock = StageClock()
    t0 = time.perf_counter()
    try:
        with ShardWriter(out / SHARDS_DIR, task.unit, cfg.shards.samples_per_shard) as writer:
            for ref in task.episodes:
                where = {"frame": None}
                try:
                    outcome = ingest_episode(ref, cfg, adapter, spool, where, clock)
                except Exception as exc:  # any failure stays inside its episode
                    failures.append(failure_entry(ref, exc, where["frame"]))
                    report_progress({"unit": task.unit, "episode_id": ref.episode_id, "frames": 0})
                    continue
                with clock.stage("write"):
                    for key, members in spool.replay():
                        writer.add_sample(key, members)
                episodes.append(outcome.record)
                dropped += [{"episode_id": ref.episode_id, "rgb_index": i, "reason": r}
                            for i, r in outcome.dropped]
                report_progress({"unit": task.unit, "episode_id": ref.episode_id,
                                 "frames": outcome.record["num_frames"]})
                _fault_hook(task.unit)
            with clock.stage("write"):
                shards = writer.close()
            samples = writer.samples
    finally:
        spool.close()
    record = {
        "unit": task.unit, "fingerprint": task.fingerprint(),
        "episode_ids": [r.episode_id for r in task.episodes],
        "shards": [dataclasses.asdict(s) for s in shards],
        "samples": [dataclasses.asdict(s) for s in samples],
        "episodes": episodes, "failures": failures, "dropped": dropped,
        "seconds": time.perf_counter() - t0, "timing": clock.as_record(),
    }
    write_bytes_atomic(unit_record_path(out, task.unit), dumps(record))
    return record


def load_valid_record(task: UnitTask) -> dict | None:
    """The unit's done record if it matches the task and its shards are intact, else None."""
    out = Path(task.out)
    path = unit_record_path(out, task.unit)
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if record.get("fingerprint") != task.fingerprint():
        return None
    for s in record.get("shards", []):
        p = out / SHARDS_DIR / s["name"]
        if not p.is_file() or p.stat().st_size != s["bytes"] or sha256_file(p) != s["sha256"]:
            return None
    return record


def unit_result(record: dict):
    from htdata.manifest import UnitResult

    return UnitResult(unit=record["unit"],
                      shards=[ShardRecord(**s) for s in record["shards"]],
                      samples=[SampleRecord(**s) for s in record["samples"]],
                      episodes=record["episodes"])


# --------------------------------------------------------------------------- the directory

def directory_identity(sources: list[Source]) -> dict:
    return {"pipelines": [s.pipeline.to_dict() for s in sources]}


def prepare_output(out: Path, identity: dict) -> None:
    """Refuse a non-empty directory that is not a previous ingest of the same pipeline(s)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()):
        state = out / WORK_DIR / STATE_FILE
        if not state.is_file():
            raise ValueError(f"{out}: directory is not empty and is not an htdata ingest output; "
                             f"refusing to write into it (choose an empty or new directory)")
        try:
            previous = json.loads(state.read_text())
        except json.JSONDecodeError:
            previous = None
        if previous != identity:
            names = [p["name"] for p in (previous or {}).get("pipelines", [])]
            raise ValueError(f"{out}: holds an ingest of different pipeline(s) {names} or different settings; "
                             f"refusing to mix datasets (use a new directory)")
    (out / WORK_DIR).mkdir(parents=True, exist_ok=True)
    (out / SHARDS_DIR).mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(out / WORK_DIR / STATE_FILE, dumps(identity))
    # Not committed while we work: a crash must not leave a manifest naming rewritten shards.
    (out / MANIFEST_FILE).unlink(missing_ok=True)


def remove_strays(out: Path, tasks: list[UnitTask]) -> None:
    """Temp files, spools, and shards/records of unit numbers outside the plan."""
    planned = {t.unit for t in tasks}
    for p in list(out.rglob(".*.tmp")) + list((out / WORK_DIR).glob("spool-*.bin")):
        p.unlink()
    for p in (out / SHARDS_DIR).glob("shard-*.tar"):
        if int(p.name.split("-")[1]) not in planned:
            p.unlink()
    for p in (out / WORK_DIR).glob("unit-*.json"):
        if int(p.stem.split("-")[1]) not in planned:
            p.unlink()


# --------------------------------------------------------------------------- commit

def commit(out: Path, sources: list[Source], records: list[dict]) -> dict:
    from htdata.layouts import load_canonical, load_layout
    from htdata.manifest import CanonicalArtifact, LayoutArtifact, commit_dataset
    from htdata.rasterise import Rasteriser

    layout_ids = sorted({lid for r in records for ep in r["episodes"] for lid in ep["layouts"].values()})
    mode = sources[0].pipeline.tactile.raster_mode
    layouts = []
    for lid in layout_ids:
        lay = load_layout(lid)
        layouts.append(LayoutArtifact(layout_id=lid, document=lay.to_dict(),
                                      coverage=Rasteriser(lay, mode=mode).coverage))
    canon = load_canonical()
    canonical = CanonicalArtifact(document=canon.to_dict(), region_map=canon.region_map, part_map=canon.part_map)
    first = sources[0].pipeline
    codec = json.loads(json.dumps(DEFAULT_CODEC_INFO))
    codec["tactile"]["compression"] = first.tactile.compression
    codec["tactile"]["raster_mode"] = mode
    codec["rgb"]["quality"] = first.rgb.quality
    codec["rgb"]["crop"] = first.rgb.crop
    codec["rgb"]["interpolation"] = first.rgb.interpolation
    srcs = [{**s.pipeline.to_dict(), "source_root": str(s.root)} for s in sources]
    return commit_dataset(out, [unit_result(r) for r in records], layouts, canonical, codec, srcs)


# --------------------------------------------------------------------------- CLI

def parse_sources(pipelines: list[str], paths: list[str]) -> tuple[list[Source], Path]:
    """Accept `--pipeline P=SRC ... OUT` or `--pipeline P [--pipeline Q] SRC [SRC2] OUT`."""
    if not pipelines:
        raise ValueError("at least one --pipeline is required")
    if not paths:
        raise ValueError("missing OUT (the dataset directory)")
    out = Path(paths[-1])
    srcs = paths[:-1]
    with_root = [p for p in pipelines if "=" in p]
    if with_root and len(with_root) != len(pipelines):
        raise ValueError("either give every --pipeline as PIPELINE=SRC or none")
    if with_root:
        if srcs:
            raise ValueError(f"with --pipeline PIPELINE=SRC give only OUT as positional, got {paths}")
        pairs = [p.split("=", 1) for p in pipelines]
    else:
        if len(srcs) != len(pipelines):
            raise ValueError(f"{len(pipelines)} pipeline(s) need {len(pipelines)} SRC folder(s) before OUT, "
                             f"got {len(srcs)}: {srcs}")
        pairs = list(zip(pipelines, srcs))
    sources = []
    for pipe, root in pairs:
        root_path = Path(root)
        if not root_path.exists():
            raise ValueError(f"source {root} (for pipeline {pipe}) does not exist")
        sources.append(Source(pipeline=load_pipeline(pipe), root=root_path.resolve()))
    names = [s.pipeline.name for s in sources]
    if len(set(names)) != len(names):
        raise ValueError(f"pipeline names must be distinct, got {names}")
    return sources, out.resolve()


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = __doc__.split("\n\n")[1]
    parser.add_argument("--pipeline", action="append", required=True, metavar="PIPELINE[=SRC]",
                        help="pipeline TOML (or a name in pipelines/); repeat for a multi-source dataset")
    parser.add_argument("paths", nargs="+", metavar="SRC... OUT",
                        help="one SRC per --pipeline (unless given as PIPELINE=SRC), then OUT")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                        help="worker processes (default: CPUs); 0 = run units in this process (debugging)")
    parser.add_argument("--executor", choices=("process", "ray"), default="process",
                        help="process: local pool, the progress bar advances per finished episode; "
                             "ray: one Ray task per work unit, the bar advances per finished unit")
    parser.add_argument("--address", default=None, help="Ray cluster address (with --executor ray)")
    parser.add_argument("--retries", type=int, default=1, help="retries of a unit that raised (default 1)")
    parser.add_argument("--allow-failures", action="store_true", help="exit 0 even if some episodes failed")
    parser.add_argument("--quiet", action="store_true",
                        help="hide the progress bar (stderr: episodes done, frames/s)")


def discover_sources(sources: list[Source]) -> tuple[list[list], list[dict]]:
    """Every source's episode refs, and one failure entry per file/episode discovery could not read.

    A bad file is a failure like a bad episode; only a source-wide problem
    (bad adapter params, unreadable annotation/split file) aborts (ValueError).
    """
    refs, failures = [], []
    for s in sources:
        name = s.pipeline.adapter.name
        try:
            found, bad = get_adapter(name).discover_all(s.root, s.pipeline.adapter.params)
        except Exception as e:
            raise ValueError(f"{s.root}: discovery with adapter {name!r} failed: {e}") from e
        refs.append(found)
        failures += [discovery_failure_entry(name, e) for e in bad]
    return refs, failures


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
           address: str | None = None, retries: int = 1, progress: bool = True) -> dict:
    """Run (or resume) an ingest; returns the report dict (also written to reports/ingest.json)."""
    t_start = time.perf_counter()
    prepare_output(out, directory_identity(sources))
    refs, discovery_failures = discover_sources(sources)
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
    n_eps = sum(len(t.episodes) for t in tasks)
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
        "episodes_planned": n_eps,
        "episodes_ingested": sum(len(r["episodes"]) for r in ordered),
        "samples": sum(len(r["samples"]) for r in ordered),
        "seconds": time.perf_counter() - t0,
        "failures": discovery_failures + [f for r in ordered for f in r["failures"]],
        "dropped_frames": [d for r in ordered for d in r["dropped"]],
        "sync": {ep["episode_id"]: ep["sync"] for r in ordered for ep in r["episodes"]},
        "timing": timing_summary([records[t.unit] for t in todo], time.perf_counter() - t_start),
    }
    # Written before the commit too, so a run that commits nothing still explains why.
    write_bytes_atomic(out / REPORT_FILE, dumps(report))
    if report["episodes_ingested"] == 0:
        raise ValueError(f"no episode could be ingested ({len(report['failures'])} failures); "
                         f"see {out / REPORT_FILE}")
    commit(out, sources, ordered)
    report["timing"]["total_s"] = time.perf_counter() - t_start
    write_bytes_atomic(out / REPORT_FILE, dumps(report))
    return report


def run(args: argparse.Namespace) -> int:
    try:
        sources, out = parse_sources(args.pipeline, args.paths)
        report = ingest(sources, out, workers=args.workers, executor=args.executor, address=args.address,
                        retries=args.retries, progress=not args.quiet)
    except (ValueError, FileNotFoundError) as e:
        print(f"htdata ingest: error: {e}", file=sys.stderr)
        return 2
    except UnitFailed as e:
        print(f"htdata ingest: error: {e}", file=sys.stderr)
        return 3
    n_fail = len(report["failures"])
    for f in report["failures"]:
        episode = f" [{f['episode_id']}]" if f["episode_id"] is not None else ""
        frame = f" frame {f['frame']}" if f["frame"] is not None else ""
        print(f"FAILED {f['file']}{episode}{frame}: {f['error']}", file=sys.stderr)
    print(f"ingested {report['episodes_ingested']}/{report['episodes_planned']} episodes, "
          f"{report['samples']} samples, {len(report['dropped_frames'])} dropped frames, {n_fail} failures "
          f"({report['units_resumed']} of {report['units']} units resumed) -> {out}", file=sys.stderr)
    if n_fail and not args.allow_failures:
        return 1
    return 0
