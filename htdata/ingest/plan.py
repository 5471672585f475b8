"""Planning an ingest: sources, discovery, layouts resolved once, work units.

Every pipeline's adapter discovers its episodes (sorted by id). Each
episode's glove layouts are then resolved ONCE here (`resolve_layouts`):
the pipeline's `[layouts]` override applied, ids looked up on the layout
search path (`--layouts DIR`, $HTDATA_LAYOUTS, the shipped layouts) and
paths taken relative to the pipeline file; the ref that goes to the
workers carries the layout ids and files, and its fingerprint covers the
layout files' bytes (an edited layout re-runs its units on resume).

A work unit is ONE episode (a long one spans several shards): units are
keyed by episode, so appending or changing an episode never moves another
(htdata/ingest/append.py decides which episodes need a unit at all). Units
are numbered from the parent version's `next_unit`, in pipeline order then
sorted episode id: fixed by the parent and the discovered episodes, never
by --workers, so a run resumed with another worker count finds the same
units and a shard name is never reused across versions.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from htdata.errors import ArgumentError, ConfigError, EpisodeError, in_context
from htdata.format.mapstorage import MapStorage
from htdata.format.table import HANDS
from htdata.glove.codecrule import dataset_gloves
from htdata.glove.layouts import load_layout
from htdata.ingest.append import labels_of
from htdata.ingest.pipeline import PipelineConfig, load_pipeline
from htdata.source.adapters import get_adapter
from htdata.source.adapters.sourcetree import RealPaths
from htdata.store.fsutil import sha256_file


@dataclass
class Source:
    """One source of an ingest.

    Args:
        pipeline: how the source's recordings become samples (htdata.ingest.pipeline.load_pipeline).
        root: the folder holding the recordings.
    """
    pipeline: PipelineConfig
    root: Path


@dataclass
class UnitTask:
    """One work unit: picklable, small (episode refs only). Built by the plan, run by an executor's worker.

    Args:
        unit: the unit number (its shard names and its done record carry it).
        out: the dataset folder being written.
        pipeline: the pipeline as a dict (PipelineConfig.to_dict()).
        pipeline_path: the pipeline file (relative paths in it resolve beside it).
        root: the source folder.
        episodes: the planned EpisodeRefs (layouts resolved), in order.
        maps: the resolved MapStorage (never AUTO).
    """
    unit: int
    out: str
    pipeline: dict          # PipelineConfig.to_dict()
    pipeline_path: str
    root: str
    episodes: list          # list[EpisodeRef], planned (layouts resolved)
    # maps stored or not, resolved by the driver (never AUTO): the pipeline dict leaves "stored" out
    # (MapStorage.pipeline_value), so the worker is told; not in the fingerprint (the dict says "raw")
    maps: MapStorage
    # the source files (resolved paths) this unit hashes: each file of the run once, by the first unit
    # in unit order that reads it (`assign_hashing`); the driver checks the digests (ingest/sourcesums.py)
    hash_files: tuple[str, ...] = ()

    @property
    def est_frames(self) -> int:
        return sum(int(r.est_frames) for r in self.episodes)

    def fingerprint(self) -> str:
        """Changes when the pipeline, the episode list, any source file, any layout file or any label changes.

        The labels (task, scene, source split) are in: a unit finished before a crash and resumed after
        the annotation table was edited must not commit the labels it was run with.
        """

        ident = {"pipeline": self.pipeline,
                 "episodes": [[r.episode_id, r.source_ref, r.fingerprint, labels_of(r)] for r in self.episodes],
                 # a resumed record must hold current digests of the files this unit hashes, also of those
                 # no ref fingerprint covers (a label table): their size and mtime are in
                 "hash_files": [[p, *_size_mtime(p)] for p in self.hash_files]}
        return hashlib.sha1(json.dumps(ident, sort_keys=True).encode()).hexdigest()

    def __repr__(self) -> str:
        return f"unit {self.unit:06d} ({len(self.episodes)} episodes)"


def _size_mtime(path: str) -> tuple[int | None, int | None]:
    try:
        st = os.stat(path)
    except OSError:   # unreadable: the unit reports it, and the run fails the file's episodes
        return None, None
    return st.st_size, st.st_mtime_ns


# Settings every pipeline of one dataset must share: the manifest records one codec and raster mode.
SHARED_SETTINGS = {
    "tactile.compression": lambda c: c.tactile.compression,
    "codec.tactile": lambda c: c.codec.tactile,
    "tactile.raster_mode": lambda c: c.tactile.raster_mode,
    "tactile.maps": lambda c: c.tactile.maps,
    "rgb.quality": lambda c: c.rgb.quality,
    "rgb.crop": lambda c: c.rgb.crop,
    "rgb.interpolation": lambda c: c.rgb.interpolation,
    "rgb.size": lambda c: c.rgb.size,
}


def check_unique_ids(refs_per_source: list[list]) -> None:
    """An episode id names one episode across all sources of a run."""
    seen: dict[str, str] = {}
    for refs in refs_per_source:
        for r in refs:
            if r.episode_id in seen:
                raise ArgumentError(f"episode id {r.episode_id!r} found twice: {seen[r.episode_id]} and {r.source_ref}")
            seen[r.episode_id] = r.source_ref


def plan_units(todo: list[tuple], out: Path, first_unit: int, real: RealPaths | None = None) -> list[UnitTask]:
    """One unit per (ref, Source) to ingest, in the order given, numbered from `first_unit`; each
    source file is hashed by the first unit that reads it (`assign_hashing`; `real`: the run's RealPaths)."""
    settings: dict[int, tuple] = {}     # per source, once: the units share the pipeline dict
    for _, src in todo:
        if id(src) not in settings:
            settings[id(src)] = (src.pipeline.to_dict(), src.pipeline.tactile.maps.decided())
    return assign_hashing([UnitTask(unit=first_unit + k, out=str(out), pipeline=settings[id(src)][0],
                                    pipeline_path=src.pipeline.path, root=str(src.root), episodes=[ref],
                                    maps=settings[id(src)][1])
                           for k, (ref, src) in enumerate(todo)], real)


def assign_hashing(tasks: list[UnitTask], real: RealPaths | None = None) -> list[UnitTask]:
    """`tasks` with `hash_files` set: every source file of the run (resolved path) goes to the first unit,
    in unit order, whose episodes read it, so a file several episodes share (an OpenTouch scene, a label
    table) is hashed once per run, by a worker, and the driver reads no source byte. Fixed by the plan
    (not by which unit finishes first), so a resumed run finds the same owners."""
    owned: set[str] = set()
    real = real or RealPaths()          # each file and folder resolved once per run
    out = []
    for t in tasks:
        mine = []
        for path in (real(p) for r in t.episodes for p in r.source_files):
            if path not in owned:
                owned.add(path)
                mine.append(path)
        out.append(dataclasses.replace(t, hash_files=tuple(mine)))
    return out


# --------------------------------------------------------------------------- sources and settings

def parse_sources(pipelines: list[str], paths: list[str]) -> tuple[list[Source], Path]:
    """The sources and OUT of `htdata ingest`: `--pipeline P=SRC ... OUT` or `--pipeline P [--pipeline Q] SRC [SRC2] OUT`.

    Args:
        pipelines: the --pipeline values (a pipeline file or shipped name, each with `=SRC` or none with it).
        paths: the positional arguments: the SRC folders (when the pipelines name none), then OUT.

    Returns:
        (one Source per pipeline, with its pipeline loaded, the OUT folder).

    Raises:
        ArgumentError: the two forms mixed, OUT missing, or SRC folders that do not match the pipelines.
    """
    if not pipelines:
        raise ArgumentError("at least one --pipeline is required")
    if not paths:
        raise ArgumentError("missing OUT (the dataset directory)")
    out = Path(paths[-1])
    srcs = paths[:-1]
    with_root = [p for p in pipelines if "=" in p]
    if with_root and len(with_root) != len(pipelines):
        raise ArgumentError("either give every --pipeline as PIPELINE=SRC or none")
    if with_root:
        if srcs:
            raise ArgumentError(f"with --pipeline PIPELINE=SRC give only OUT as positional, got {paths}")
        pairs = [p.split("=", 1) for p in pipelines]
    else:
        if len(srcs) != len(pipelines):
            raise ArgumentError(f"{len(pipelines)} pipeline(s) need {len(pipelines)} SRC folder(s) before OUT, "
                                f"got {len(srcs)}: {srcs}")
        pairs = list(zip(pipelines, srcs))
    sources = []
    for pipe, root in pairs:
        root_path = Path(root)
        if not root_path.exists():
            raise ArgumentError(f"source {root} (for pipeline {pipe}) does not exist")
        sources.append(Source(pipeline=load_pipeline(pipe), root=root_path.resolve()))
    names = [s.pipeline.name for s in sources]
    if len(set(names)) != len(names):
        raise ConfigError(f"pipeline names must be distinct, got {names}")
    return sources, out.resolve()


def check_settings_agree(sources: list[Source]) -> None:
    """Refuse pipelines whose codec or raster settings differ (one dataset records one of each)."""
    first = sources[0].pipeline
    for s in sources[1:]:
        for name, get in SHARED_SETTINGS.items():
            a, b = get(first), get(s.pipeline)
            if a != b:
                raise ConfigError(f"pipelines {first.name!r} ({first.path}) and {s.pipeline.name!r} ({s.pipeline.path}) "
                                  f"disagree on {name}: {a!r} vs {b!r}; a dataset has one codec and raster "
                                  f"setting: make them equal or ingest into separate datasets")


def resolve_sources(sources: list[Source], refs_per_source: list[list], existing: dict | None = None) -> list[Source]:
    """`sources` with their pipelines' [codec] resolved for this run (htdata/glove/codecrule.py's rule).

    Gloves = every layout the run's planned refs use (`ref.layout_files`),
    under each source's normalisation; `existing` = the parent version's
    manifest "codec" -> "tactile" (None for a new dataset). The pipelines must
    agree on [codec] tactile and [tactile] compression (one codec per dataset).
    """
    if not sources:
        return []
    settings = {(s.pipeline.codec.tactile, s.pipeline.tactile.compression) for s in sources}
    if len(settings) > 1:
        raise ConfigError(f"pipelines {[s.pipeline.name for s in sources]} disagree on [codec] tactile / "
                          f"[tactile] compression ({sorted(settings)}): a dataset has one codec")
    first = sources[0].pipeline
    # each distinct layout file once per source (not once per episode: a large run has ~10^5 of them)
    pairs = [(s.pipeline.normalise_settings(), load_layout(path)) for s, refs in zip(sources, refs_per_source)
             for path in sorted({p for r in refs for p in r.layout_files.values()})]
    choice = first.codec.resolve(first.tactile.compression, dataset_gloves(pairs), existing)
    return [dataclasses.replace(s, pipeline=s.pipeline.with_codec_choice(choice)) for s in sources]


# --------------------------------------------------------------------------- layouts, resolved once

def pipeline_layout_base(cfg: PipelineConfig) -> Path | None:
    """Folder relative layout paths in the pipeline's [layouts] are taken from (the pipeline file's)."""
    p = Path(cfg.path) if cfg.path else None
    return p.parent if p is not None and p.suffix == ".toml" else None


def check_pipeline_layouts(cfg: PipelineConfig, dirs: tuple = ()) -> None:
    """Every [layouts] override of the pipeline resolves (LayoutNotFound / ValueError otherwise)."""
    for hand, name in cfg.layouts.items():
        try:
            load_layout(name, dirs, pipeline_layout_base(cfg))
        except (FileNotFoundError, ValueError) as e:
            raise type(e)(f"{cfg.path or cfg.name}: [layouts] {hand}: {e}") from None


class LayoutLookup:
    """`load_layout` and the layout file's sha256, once per (name, folders, base) and file in a run:
    planning resolves every episode's layouts, and ~10^5 episodes share a handful of layouts."""

    def __init__(self, dirs: tuple = ()):
        self.dirs = tuple(dirs)
        self._layouts: dict[tuple, object] = {}
        self._digests: dict[str, str] = {}

    def load(self, name, base=None):
        key = (str(name), str(base) if base is not None else None)
        if key not in self._layouts:
            self._layouts[key] = load_layout(name, self.dirs, base)
        return self._layouts[key]

    def digest(self, path: str) -> str:
        if path not in self._digests:
            self._digests[path] = sha256_file(Path(path))
        return self._digests[path]


def resolve_layouts(ref, cfg: PipelineConfig, dirs: tuple | LayoutLookup = ()):
    """`ref` with its layouts resolved: ids in `layouts`, files in `layout_files`, fingerprint over their bytes.

    `dirs`: the layout folders (`--layouts`), or a `LayoutLookup` over them that a run shares."""
    lookup = dirs if isinstance(dirs, LayoutLookup) else LayoutLookup(dirs)
    ids, files, digests = {}, {}, {}
    for h in (h for h in HANDS if h in ref.hands):
        if h in cfg.layouts:
            layout = lookup.load(cfg.layouts[h], pipeline_layout_base(cfg))
        elif h in ref.layouts:
            named_in = ref.extra.get("layouts_from") if isinstance(ref.extra, dict) else None
            try:
                layout = lookup.load(ref.layouts[h])
            except (FileNotFoundError, ValueError) as e:
                if not named_in:
                    raise
                # the file that names the layout, so the user knows where the (mis-spelt) id comes from
                raise EpisodeError(ref, None, f"{h} hand: {e}", file=named_in) from None
        else:
            raise EpisodeError(ref, None, f"no layout for the {h} hand (neither the source nor the pipeline's "
                               f"[layouts] names one)")
        ids[h], files[h] = layout.layout_id, layout.path
        digests[h] = lookup.digest(layout.path)
    fingerprint = hashlib.sha1(json.dumps([ref.fingerprint, digests], sort_keys=True).encode()).hexdigest()
    return dataclasses.replace(ref, layouts=ids, layout_files=files, fingerprint=fingerprint)


def check_names_in_use(source: Source, found: list, planned: list, failed: list[dict], dirs: tuple = ()) -> None:
    """The pipeline's [layouts] / [normalise.*] ids are used by the source's recordings (PipelineConfig.
    check_layout_names); skipped when nothing was planned (the failures say why).

    A hand a recording has but could not use (`hands_excluded`, e.g. an all-NaN TouchAnything grid) still
    counts: the glove is there, so its [layouts] entry and the [normalise] table of a layout for that hand
    are not typos.
    """
    if not planned:
        return
    why = ""
    if failed:
        f = failed[0]
        why = (f" ({len(failed)} recording(s) of this source could not be planned and are not counted, e.g. "
               f"{f['file']}: {f['error']})")
    used = {lid for r in planned for lid in r.layouts.values()}
    excluded = {h for r in found if isinstance(r.extra, dict) for h in r.extra.get("hands_excluded", {})}
    for lid in set(source.pipeline.normalise) - used if excluded else ():
        try:
            if load_layout(lid, dirs).hand in excluded:
                used.add(lid)
        except (FileNotFoundError, ValueError):
            pass
    source.pipeline.check_layout_names(used, {h for r in found for h in r.hands} | excluded,
                                       f"source {source.root}", why)


def check_layout_ids_unique(refs: list) -> None:
    """One layout id = one file: a dataset's layouts/ holds one document per id."""
    seen: dict[str, str] = {}
    for r in refs:
        for h, lid in r.layouts.items():
            path = r.layout_files[h]
            other = seen.setdefault(lid, path)
            if other != path and sha256_file(Path(other)) != sha256_file(Path(path)):
                raise ConfigError(f"layout id {lid!r} names two different files: {other} and {path} "
                                  f"(episode {r.episode_id}); give one of them another layout_id")


def failure_entry(stage: str, source: str, exc: EpisodeError, source_ref: str | None = None) -> dict:
    """A report failure for an episode or file that never reached a unit (episode_id may be None)."""
    return {"stage": stage, "episode_id": exc.episode_id, "source": source, "source_ref": source_ref or exc.file,
            "file": exc.file, "frame": exc.frame, "error": exc.message}


def discover_sources(sources: list[Source], layout_dirs: tuple = ()) -> tuple[list[list], list[dict]]:
    """Every source's planned episode refs, and one failure entry per file/episode that cannot be planned.

    A bad file (discovery) or an episode whose layout does not resolve
    (stage "plan") is a failure like a bad episode; only a source-wide
    problem (bad adapter params, unreadable annotation/split file, a
    pipeline [layouts] override that does not resolve) aborts with the adapter's own error type (a
    ConfigError, a DatasetError, an OSError ...), its message naming the source and the adapter.
    """
    refs, failures = [], []
    lookup = LayoutLookup(layout_dirs)
    for s in sources:
        check_pipeline_layouts(s.pipeline, layout_dirs)
        name = s.pipeline.adapter.name
        try:
            found, bad = get_adapter(name).discover_all(s.root, s.pipeline.adapter.params)
        except Exception as e:   # the error keeps its type (a ConfigError stays one), its message says where
            again = in_context(e, f"{s.root}: discovery with adapter {name!r} failed")
            if again is None:
                raise
            raise again from e
        failures += [failure_entry("discovery", name, e) for e in bad]
        planned, failed = [], []
        for ref in found:
            try:
                planned.append(resolve_layouts(ref, s.pipeline, lookup))
            except (FileNotFoundError, ValueError, EpisodeError) as e:
                err = e if isinstance(e, EpisodeError) else EpisodeError(ref, None, str(e))
                failed.append(failure_entry("plan", name, err, ref.source_ref))
        failures += failed
        check_names_in_use(s, found, planned, failed, layout_dirs)
        refs.append(planned)
    check_layout_ids_unique([r for rs in refs for r in rs])
    return refs, failures
