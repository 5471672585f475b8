"""Every benchmark side by side, one run, one report (`htdata bench`, `make bench`).

`run_bench(cfg)` writes OUT/results.json (every number) and OUT/REPORT.md
(tables, chosen defaults with their reasons, targets met or missed). Scratch
data (sample corpus, datasets, synthetic long episodes, index files) goes to
OUT/.work, reused across runs only for the deterministic sample corpus.

Built-in sections live in htdata/benchmarks/ (one module per area). Other
packages add sections through the entry point group "htdata.bench_sections":
each entry point loads a callable `section(ctx) -> dict` that receives a
`SectionContext` (an ingested sample dataset, a scratch folder, quick, seed)
and returns JSON-able results; an optional "markdown" string is rendered
verbatim in REPORT.md under a heading with the section's name. Discovered
sections run after the built-in ones, so htdata never imports their code
(HandTouch's training benchmark is one). A section that fails, built-in or
discovered, is recorded under "errors" and the others still run.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path

from htdata.benchmarks.append import append_rows
from htdata.benchmarks.codecs import codec_rows, real_maps
from htdata.benchmarks.dataloader import dataloader_rows
from htdata.benchmarks.driver import driver_rows
from htdata.benchmarks.export import export_rows
from htdata.benchmarks.htbenchsize import size_rows
from htdata.benchmarks.index import index_rows
from htdata.benchmarks.ingest import adapter_rows, ingest_run, peak_rss_rows, write_long_touchanything
from htdata.benchmarks.lag import lag_rows
from htdata.benchmarks.loader import loader_rows
from htdata.benchmarks.machine import machine_info
from htdata.benchmarks.maps import maps_rows
from htdata.benchmarks.raster import raster_rows
from htdata.benchmarks.raw import raw_rows
from htdata.benchmarks.rawglove import rawglove_rows
from htdata.benchmarks.realglove import realglove_rows
from htdata.benchmarks.report import render_report
from htdata.benchmarks.revisions import ROUND_ONE, revision_rows
from htdata.benchmarks.rgb import rgb_section
from htdata.benchmarks.scaling import scaling_rows
from htdata.benchmarks.sources import discover, source_rgb_frames
from htdata.benchmarks.stats import stats_rows
from htdata.benchmarks.validation import validate_rows
from htdata.benchmarks.view import view_rows
from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic
from htdata.synthetic.corpus import FORMATS, SCALES, CorpusConfig, corpus_complete, write_corpus
from htdata.workers import usable_cores

SECTION_GROUP = "htdata.bench_sections"
BUILTIN_SECTIONS = ("codecs", "rgb", "raster", "ingest", "scaling", "driver", "rss", "loader", "index", "validate",
                    "append", "stats", "lag", "raw", "maps", "export", "rawglove", "view", "realglove", "size")
# Top-level keys of results.json that are not sections: no section may take these names.
RESERVED_KEYS = ("command", "quick", "created", "config", "machine", "timings_s", "errors", "plugins", "seconds",
                 "gpu_check")
# `make gpu-check` runs on a machine with a GPU, apart from this run: its JSON, left in OUT, is shown
# in REPORT.md under its own heading with the machine it ran on (never mixed into this run's ratios).
GPU_CHECK_FILE = "gpucheck.json"


@dataclass
class BenchConfig:
    out: Path
    quick: bool = False
    seed: int = 0
    scale: str = "small"                   # sample corpus scale
    scaling_scale: str = "medium"          # the corpus of the 1 -> 2 worker runs (enough units)
    ingest_reps: int = 3                   # ours vs the bare bound, alternated
    scaling_reps: int = 2                  # 1 vs 2 workers, alternated
    revision: str | None = ROUND_ONE       # the ingest section's revision rows (None: none)
    revision_frames: int = 600             # the moving TouchAnything episode they ingest
    codec_maps_per_glove: int = 96         # per glove layout
    rgb_frames: int = 12
    raster_frames: int = 256
    # 1 -> N workers, N = the machine's usable cores (at least 2)
    ingest_workers: tuple[int, ...] = field(default_factory=lambda: (1, max(2, usable_cores())))
    driver_scales: tuple[str, str] = ("tiny", "medium")   # the driver's serial work at two corpus sizes
    driver_sources: tuple[str, ...] | None = None         # None: every source format
    driver_episode_frames: tuple[int, int] | None = None  # None: the scales' episodes; (lo, hi): long ones
    rss_lengths: tuple[int, ...] = (150, 600, 2400)
    loader_random: int = 400
    loader_windows: int = 100
    dataloader_items: int = 2000           # items per timed DataLoader epoch
    index_rows: tuple[int, ...] = (1_000_000, 10_000_000)
    size_samples: tuple[int, ...] = (1_000_000, 3_000_000)   # the replicated dataset (htbenchsize.py), samples
    validate_workers: tuple[int, ...] = (1, 2)
    append_sizes: tuple[int, ...] = (20, 200)    # episodes before the one appended (an order of magnitude apart)
    view_lengths: tuple[int, ...] = (150, 600)   # episodes saved with `htdata view --save` (600: issue #38's target)
    sections: tuple[str, ...] | None = None   # None: every built-in and discovered section
    real_glove: Path | None = None         # real raw-count recordings (section "realglove"; None: it says so)

    @classmethod
    def quick_config(cls, out: Path, seed: int = 0) -> "BenchConfig":
        return cls(out=out, quick=True, seed=seed, scale="tiny", scaling_scale="tiny", ingest_reps=1,
                   scaling_reps=1, revision=None, codec_maps_per_glove=8, rgb_frames=2,
                   raster_frames=8, rss_lengths=(20, 40), loader_random=20, loader_windows=5, dataloader_items=64,
                   index_rows=(10_000,), size_samples=(5_000,), append_sizes=(2, 20), view_lengths=(20, 40), driver_scales=("tiny", "small"),
                   driver_sources=("opentouch",))

    def validate(self) -> "BenchConfig":
        self.out = Path(self.out)
        for name in ("scale", "scaling_scale"):
            if getattr(self, name) not in SCALES:
                raise ArgumentError(f"{name} must be one of {SCALES}, got {getattr(self, name)!r}")
        if len(self.driver_scales) != 2 or [SCALES.index(s) for s in self.driver_scales if s in SCALES] != sorted(
                {SCALES.index(s) for s in self.driver_scales if s in SCALES}) or len(set(self.driver_scales)) != 2:
            raise ArgumentError(f"driver_scales must be two corpus scales of {SCALES}, smaller first, got "
                                f"{self.driver_scales}")
        unknown = [s for s in (self.driver_sources or ()) if s not in FORMATS]
        if unknown or self.driver_sources == ():
            raise ArgumentError(f"driver_sources must be None or formats of {FORMATS}, got {self.driver_sources}")
        if min(self.ingest_reps, self.scaling_reps, self.revision_frames) < 1:
            raise ArgumentError("ingest_reps, scaling_reps and revision_frames must be >= 1")
        positive = {"codec_maps_per_glove": self.codec_maps_per_glove, "rgb_frames": self.rgb_frames,
                    "raster_frames": self.raster_frames, "loader_random": self.loader_random,
                    "loader_windows": self.loader_windows, "dataloader_items": self.dataloader_items}
        bad = {k: v for k, v in positive.items() if not isinstance(v, int) or v < 1}
        if bad:
            raise ArgumentError(f"bench sizes must be integers >= 1, got {bad}")
        if len(set(self.ingest_workers)) < 2 or min(self.ingest_workers) < 1:
            raise ArgumentError(f"ingest_workers must name two worker counts >= 1 (1 -> N scaling), "
                                f"got {self.ingest_workers}")
        if len(self.rss_lengths) < 2 or list(self.rss_lengths) != sorted(set(self.rss_lengths)) or self.rss_lengths[0] < 2:
            raise ArgumentError(f"rss_lengths must be >= 2 increasing lengths >= 2 frames, got {self.rss_lengths}")
        if len(self.append_sizes) < 2 or min(self.append_sizes) < 1:
            raise ArgumentError(f"append_sizes must be >= 2 dataset sizes >= 1, got {self.append_sizes}")
        if not self.size_samples or min(self.size_samples) < 1:
            raise ArgumentError(f"size_samples must be positive, got {self.size_samples}")
        if not self.index_rows or min(self.index_rows) < 1:
            raise ArgumentError(f"index_rows must be positive, got {self.index_rows}")
        if self.sections is not None:
            known = BUILTIN_SECTIONS + tuple(discover_sections())
            unknown = [s for s in self.sections if s not in known]
            if unknown or not self.sections:
                raise ArgumentError(f"unknown section(s) {unknown or list(self.sections)}; known: {list(known)}")
        return self

    @property
    def work(self) -> Path:
        return self.out / ".work"


@dataclass(frozen=True)
class SectionContext:
    """What a discovered section gets: `section(ctx) -> dict`."""

    dataset: Path      # every sample source ingested into one committed dataset
    work: Path         # scratch folder of this section (exists, kept between runs)
    quick: bool        # tiny sizes: a smoke run
    seed: int


def discover_sections() -> dict[str, metadata.EntryPoint]:
    """Installed sections of the entry point group, by name (not loaded yet)."""
    return {ep.name: ep for ep in sorted(metadata.entry_points(group=SECTION_GROUP), key=lambda e: e.name)}


def bench_sources() -> tuple[str, ...]:
    """Sources benchmarked: the sample corpus formats, named like their adapter and shipped pipeline."""

    return FORMATS


def ensure_corpus(cfg: BenchConfig, scale: str | None = None, formats: tuple[str, ...] = FORMATS,
                  episode_frames: tuple[int, int] | None = None) -> Path:
    """The deterministic sample corpus (`formats`, `episode_frames`); reused when a complete one of it exists."""

    scale = scale or cfg.scale
    formats = tuple(f for f in FORMATS if f in formats)
    root = cfg.work / (f"raw_{scale}_{cfg.seed}" + ("" if formats == FORMATS else "_" + "_".join(formats))
                       + ("" if episode_frames is None else "_frames{}-{}".format(*episode_frames)))
    corpus = CorpusConfig(out=root, seed=cfg.seed, scale=scale, formats=formats, progress=False, overwrite=True,
                          episode_frames=episode_frames)
    if not corpus_complete(corpus):
        write_corpus(corpus)
    return root


def finite_json(obj):
    """Plain JSON types; non-finite floats become None (results.json stays strict JSON)."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


class Sections:
    """Runs the benchmark sections in order, sharing the corpus and datasets they need."""

    def __init__(self, cfg: BenchConfig, log: Callable[[str], None]):
        self.cfg, self.log = cfg, log
        self._corpus: Path | None = None
        self._dataset: Path | None = None

    @property
    def corpus(self) -> Path:
        if self._corpus is None:
            self.log(f"sample corpus ({self.cfg.scale})")
            self._corpus = ensure_corpus(self.cfg)
        return self._corpus

    @property
    def dataset(self) -> Path:
        """Every source in one dataset, ingested with the most workers (loader, validate, plugins)."""
        if self._dataset is None:
            out = self.cfg.work / "dataset_all"
            self.log("ingest: all sources into one dataset")
            self.combined_run = ingest_run([(s, self.corpus / s) for s in bench_sources()], out,
                                           max(self.cfg.ingest_workers), ("tactile.maps=stored",))
            self._dataset = out
        return self._dataset

    def codecs(self) -> dict:
        return codec_rows(real_maps(self.corpus, bench_sources(), self.cfg.codec_maps_per_glove))

    def rgb(self) -> dict:

        frames = []
        sources = bench_sources()
        for name in sources:     # every camera resolution of the corpus
            pcfg, adapter, refs = discover(name, self.corpus / name)
            frames += source_rgb_frames(adapter, pcfg, refs[0], max(1, self.cfg.rgb_frames // len(sources)))
        by_size: dict[tuple, list] = {}
        for f in frames:
            by_size.setdefault(f.shape, []).append(f)
        # resize_rows needs one source size per table: the largest camera frames (most aliasing).
        largest = max(by_size, key=lambda s: s[0] * s[1])
        section = rgb_section(by_size[largest])
        section["source_sizes_available"] = [f"{s[1]}x{s[0]}" for s in by_size]
        return section

    def raster(self) -> dict:
        return raster_rows(self.cfg.raster_frames)

    def ingest(self) -> dict:
        result = adapter_rows(self.corpus, self.cfg.work, bench_sources(), self.cfg.ingest_reps)
        # the default stores the maps (EXR encoded by us and by the bound); the same with the "raw" opt-in
        result["maps_raw"] = adapter_rows(self.corpus, self.cfg.work, bench_sources(), self.cfg.ingest_reps,
                                          ("tactile.maps=raw",))
        self.dataset   # noqa: B018 (build the combined dataset now so its run is reported here)
        result["runs"].append(self.combined_run)
        if self.cfg.revision:
            episode = self.cfg.work / f"long_touchanything_{self.cfg.revision_frames}"
            if not episode.exists():
                write_long_touchanything(episode, self.cfg.revision_frames)
            self.log(f"ingest: revision {self.cfg.revision} vs current code")
            result["revision"] = revision_rows(self.cfg.work, episode, self.corpus, self.cfg.revision)
        return result

    def scaling(self) -> dict:
        self.log(f"sample corpus ({self.cfg.scaling_scale})")
        corpus = ensure_corpus(self.cfg, self.cfg.scaling_scale)
        workers = (min(self.cfg.ingest_workers), max(self.cfg.ingest_workers))
        return scaling_rows(corpus, self.cfg.work, bench_sources(), workers, self.cfg.scaling_reps)

    def driver(self) -> dict:
        sources = self.cfg.driver_sources or bench_sources()
        corpora = []
        for scale in self.cfg.driver_scales:
            self.log(f"sample corpus ({scale})")
            corpora.append(ensure_corpus(self.cfg, scale, FORMATS if self.cfg.driver_sources is None else sources,
                                         self.cfg.driver_episode_frames))
        return driver_rows(tuple(corpora), self.cfg.driver_scales, self.cfg.work, sources,
                           max(self.cfg.ingest_workers), self.cfg.scaling_reps, self.cfg.driver_episode_frames)

    def rss(self) -> list:
        return peak_rss_rows(self.cfg.work, self.cfg.rss_lengths)

    def loader(self) -> dict:
        result = loader_rows(self.dataset, self.cfg.loader_random, self.cfg.loader_windows, self.cfg.seed)
        workers = (min(self.cfg.ingest_workers), max(self.cfg.ingest_workers))
        result["dataloader"] = dataloader_rows(self.dataset, workers, self.cfg.scaling_reps,
                                               self.cfg.dataloader_items, seed=self.cfg.seed)
        return result

    def index(self) -> list:
        tmp = self.cfg.work / "index"
        tmp.mkdir(parents=True, exist_ok=True)
        return index_rows(self.cfg.index_rows, tmp)

    def validate(self) -> list:
        return validate_rows(self.dataset, self.cfg.validate_workers)

    def append(self) -> dict:
        return append_rows(self.cfg.work, self.cfg.append_sizes)

    def stats(self) -> dict:
        return stats_rows(self.dataset)

    def lag(self) -> dict:
        return lag_rows(self.cfg.work, self.cfg.quick, self.cfg.seed)

    def raw(self) -> dict:
        return raw_rows(self.corpus, self.cfg.work, bench_sources(), self.dataset, self.cfg.quick)

    def maps(self) -> dict:
        return maps_rows(self.corpus, self.cfg.work, bench_sources(), self.cfg.quick, self.cfg.real_glove)

    def export(self) -> dict:
        return export_rows(self.dataset, self.cfg.work)

    def rawglove(self) -> dict:
        return rawglove_rows(self.cfg.quick, self.cfg.seed)

    def view(self) -> dict:
        return view_rows(self.cfg.work, self.cfg.view_lengths, again=not self.cfg.quick)

    def size(self) -> dict:
        return size_rows(self.cfg.work / "size", self.cfg.size_samples)

    def realglove(self) -> dict:
        return realglove_rows(self.cfg.real_glove, self.cfg.work / "realglove", self.cfg.quick)

    def discovered(self, name: str, entry_point: metadata.EntryPoint) -> dict:
        """Load and run one discovered section; its result must be a JSON-able dict."""
        section = entry_point.load()
        work = self.cfg.work / "sections" / name
        work.mkdir(parents=True, exist_ok=True)
        result = section(SectionContext(dataset=self.dataset, work=work, quick=self.cfg.quick, seed=self.cfg.seed))
        if not isinstance(result, dict):
            raise TypeError(f"{entry_point.value} returned {type(result).__name__}, expected a dict")
        if not isinstance(result.get("markdown", ""), str):
            raise TypeError(f"{entry_point.value}: 'markdown' must be a string")
        try:
            json.dumps(finite_json(result), allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{entry_point.value} returned results that are not JSON-able: {exc}") from None
        return result


def run_bench(cfg: BenchConfig, command: str = "htdata bench",
              log: Callable[[str], None] | None = None) -> dict:
    """Run the sections; write OUT/results.json and OUT/REPORT.md; return the results.

    `log(message)` receives progress lines (section starts, failures with traceback).
    """

    cfg.validate()
    cfg.work.mkdir(parents=True, exist_ok=True)
    log = log or (lambda message: None)
    plugins = discover_sections()
    wanted = cfg.sections or BUILTIN_SECTIONS + tuple(plugins)
    t_start = time.perf_counter()
    results: dict = {"command": command, "quick": cfg.quick,
                     "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                     "config": {k: v for k, v in asdict(cfg).items() if k != "out"},
                     "machine": machine_info(), "timings_s": {}, "errors": {}, "plugins": {}}
    for name, ep in list(plugins.items()):
        if name in BUILTIN_SECTIONS + RESERVED_KEYS:   # never displaces a built-in section or a key
            results["errors"][f"{name} ({ep.value})"] = (f"ValueError: entry point named {name!r}, which a "
                                                         "built-in section or a results.json key already uses")
            del plugins[name]
        elif name in wanted:
            results["plugins"][name] = ep.value
    sections = Sections(cfg, log)
    # Built-in sections first, then discovered ones (in name order).
    for name in [s for s in BUILTIN_SECTIONS if s in wanted] + [s for s in plugins if s in wanted]:
        log(name)
        t0 = time.perf_counter()
        try:
            if name in plugins:
                results[name] = sections.discovered(name, plugins[name])
            else:
                results[name] = getattr(sections, name)()
        except Exception as exc:   # one broken section must not hide the others' numbers
            results["errors"][name] = f"{type(exc).__name__}: {exc}"
            log(f"{name} FAILED: {exc}\n{traceback.format_exc()}")
        results["timings_s"][name] = time.perf_counter() - t0
    results["machine"]["loadavg_1m_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    results["seconds"] = time.perf_counter() - t_start
    gpu = cfg.out / GPU_CHECK_FILE
    if gpu.is_file():
        results["gpu_check"] = {"file": GPU_CHECK_FILE, **json.loads(gpu.read_text())}
    results = finite_json(results)
    write_bytes_atomic(cfg.out / "results.json", (json.dumps(results, indent=2, allow_nan=False) + "\n").encode())
    write_bytes_atomic(cfg.out / "REPORT.md", render_report(results).encode())
    log(f"wrote {cfg.out / 'results.json'} and {cfg.out / 'REPORT.md'}")
    return results
