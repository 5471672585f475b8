"""`htdata bench` (`make bench`): every benchmark side by side, one run, one report.

    htdata bench --out bench            # full: ~6-10 min on 2 cores
    htdata bench --quick --out /tmp/b   # tiny sizes (tests)

Writes OUT/results.json (every number) and OUT/REPORT.md (tables, chosen
defaults with their reasons, targets met or missed). Scratch data (sample
corpus, datasets, synthetic long episodes, index files) goes to OUT/.work,
reused across runs only for the deterministic sample corpus.
A section that fails is recorded under "errors" and the command exits 1.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import shutil
import sys
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

ADAPTERS = ("opentouch", "touchanything", "native")


@dataclass
class BenchConfig:
    out: Path
    quick: bool = False
    seed: int = 0
    scale: str = "small"                   # sample corpus scale
    codec_maps_per_glove: int = 96
    rgb_frames: int = 12
    raster_frames: int = 256
    ingest_workers: tuple[int, ...] = (1, 2)
    rss_lengths: tuple[int, ...] = (150, 600, 2400)
    loader_random: int = 400
    loader_windows: int = 100
    index_rows: tuple[int, ...] = (1_000_000, 10_000_000)
    validate_workers: tuple[int, ...] = (1, 2)
    train_steps: int = 40
    train_warmup: bool = True
    sections: tuple[str, ...] = field(default_factory=lambda: (
        "codecs", "rgb", "raster", "ingest", "rss", "loader", "index", "validate", "training"))

    @classmethod
    def quick_config(cls, out: Path, seed: int = 0) -> "BenchConfig":
        return cls(out=out, quick=True, seed=seed, scale="tiny", codec_maps_per_glove=8, rgb_frames=2,
                   raster_frames=8, rss_lengths=(20, 40), loader_random=20, loader_windows=5,
                   index_rows=(10_000,), train_steps=2, train_warmup=False)

    def validate(self) -> "BenchConfig":
        self.out = Path(self.out)
        if self.scale not in ("tiny", "small"):
            raise ValueError(f"scale must be tiny or small, got {self.scale!r}")
        positive = {"codec_maps_per_glove": self.codec_maps_per_glove, "rgb_frames": self.rgb_frames,
                    "raster_frames": self.raster_frames, "loader_random": self.loader_random,
                    "loader_windows": self.loader_windows, "train_steps": self.train_steps}
        bad = {k: v for k, v in positive.items() if not isinstance(v, int) or v < 1}
        if bad:
            raise ValueError(f"bench sizes must be integers >= 1, got {bad}")
        if not self.ingest_workers or min(self.ingest_workers) < 1:
            raise ValueError(f"ingest_workers must be >= 1, got {self.ingest_workers}")
        if len(self.rss_lengths) < 2 or list(self.rss_lengths) != sorted(set(self.rss_lengths)) or self.rss_lengths[0] < 2:
            raise ValueError(f"rss_lengths must be >= 2 increasing lengths >= 2 frames, got {self.rss_lengths}")
        if not self.index_rows or min(self.index_rows) < 1:
            raise ValueError(f"index_rows must be positive, got {self.index_rows}")
        return self

    @property
    def work(self) -> Path:
        return self.out / ".work"


def ensure_corpus(cfg: BenchConfig) -> Path:
    """The deterministic sample corpus; reused when a complete one of the same scale/seed exists."""
    from htdata.sample.corpus import CorpusConfig, write_corpus

    root = cfg.work / f"raw_{cfg.scale}_{cfg.seed}"
    marker = root / ".complete"
    if not marker.is_file():
        if root.exists():
            shutil.rmtree(root)
        write_corpus(CorpusConfig(out=root, seed=cfg.seed, scale=cfg.scale, progress=False))
        marker.write_text("ok\n")
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

    def __init__(self, cfg: BenchConfig, log):
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
        """All three adapters in one dataset, ingested with the most workers (loader/validate/train)."""
        if self._dataset is None:
            from htdata.benchmarks.ingest import ingest_run

            out = self.cfg.work / "dataset_all"
            self.log("ingest: all adapters into one dataset")
            self.combined_run = ingest_run([(a, self.corpus / a) for a in ADAPTERS], out,
                                           max(self.cfg.ingest_workers))
            self._dataset = out
        return self._dataset

    def codecs(self) -> dict:
        from htdata.benchmarks.codecs import codec_rows, real_maps

        maps = {g: real_maps(self.corpus, g, self.cfg.codec_maps_per_glove) for g in ("opentouch", "touchanything")}
        return codec_rows(maps)

    def rgb(self) -> dict:
        from htdata.benchmarks.rgb import rgb_section
        from htdata.benchmarks.sources import discover, source_rgb_frames

        frames = []
        for name in ADAPTERS:     # every camera resolution of the corpus
            pcfg, adapter, refs = discover(name, self.corpus / name)
            frames += source_rgb_frames(adapter, pcfg, refs[0], max(1, self.cfg.rgb_frames // len(ADAPTERS)))
        by_size: dict[tuple, list] = {}
        for f in frames:
            by_size.setdefault(f.shape, []).append(f)
        # resize_rows needs one source size per table: the largest camera frames (most aliasing).
        largest = max(by_size, key=lambda s: s[0] * s[1])
        section = rgb_section(by_size[largest])
        section["source_sizes_available"] = [f"{s[1]}x{s[0]}" for s in by_size]
        return section

    def raster(self) -> list:
        from htdata.benchmarks.raster import raster_rows

        return raster_rows(self.cfg.raster_frames)

    def ingest(self) -> dict:
        from htdata.benchmarks.ingest import adapter_rows

        result = adapter_rows(self.corpus, self.cfg.work, ADAPTERS, self.cfg.ingest_workers)
        self.dataset   # noqa: B018 (build the combined dataset now so its run is reported here)
        result["runs"].append(self.combined_run)
        return result

    def rss(self) -> list:
        from htdata.benchmarks.ingest import peak_rss_rows

        return peak_rss_rows(self.cfg.work, self.cfg.rss_lengths)

    def loader(self) -> dict:
        from htdata.benchmarks.loader import loader_rows

        return loader_rows(self.dataset, self.cfg.loader_random, self.cfg.loader_windows, self.cfg.seed)

    def index(self) -> list:
        from htdata.benchmarks.loader import index_rows

        tmp = self.cfg.work / "index"
        tmp.mkdir(parents=True, exist_ok=True)
        return index_rows(self.cfg.index_rows, tmp)

    def validate(self) -> list:
        from htdata.benchmarks.validation import validate_rows

        return validate_rows(self.dataset, self.cfg.validate_workers)

    def training(self) -> dict:
        from htdata.benchmarks.training import training_rows

        return training_rows(self.dataset, self.cfg.work, self.cfg.train_steps,
                             warmup=self.cfg.train_warmup)


def run_bench(cfg: BenchConfig, command: str = "htdata bench", progress: bool = True) -> dict:
    """Run every section; write OUT/results.json and OUT/REPORT.md; return the results."""
    from htdata.benchmarks.machine import machine_info
    from htdata.benchmarks.report import render_report

    cfg.validate()
    cfg.work.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    def log(msg: str) -> None:
        if progress:
            print(f"[bench {time.perf_counter() - t_start:6.1f}s] {msg}", file=sys.stderr, flush=True)

    results: dict = {"command": command, "quick": cfg.quick,
                     "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                     "config": {k: v for k, v in asdict(cfg).items() if k != "out"},
                     "machine": machine_info(), "timings_s": {}, "errors": {}}
    sections = Sections(cfg, log)
    for name in cfg.sections:
        log(name)
        t0 = time.perf_counter()
        try:
            results[name] = getattr(sections, name)()
        except Exception as exc:   # one broken section must not hide the others' numbers
            results["errors"][name] = f"{type(exc).__name__}: {exc}"
            log(f"{name} FAILED: {exc}\n{traceback.format_exc()}")
        results["timings_s"][name] = time.perf_counter() - t0
    results["machine"]["loadavg_1m_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    results["seconds"] = time.perf_counter() - t_start
    results = finite_json(results)
    cfg.out.mkdir(parents=True, exist_ok=True)
    for name, text in (("results.json", json.dumps(results, indent=2, allow_nan=False) + "\n"),
                       ("REPORT.md", render_report(results))):
        tmp = cfg.out / f".{name}.tmp"
        tmp.write_text(text)
        os.replace(tmp, cfg.out / name)
    log(f"wrote {cfg.out / 'results.json'} and {cfg.out / 'REPORT.md'}")
    return results


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = __doc__.split("\n\n")[1]
    parser.add_argument("--out", type=Path, default=Path("bench"), help="output folder (default: bench)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: a smoke run of every section (< 1 min)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sample corpus and of random access")
    parser.add_argument("--only", default=None, metavar="A,B",
                        help="comma-separated sections to run (default: all)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    cfg = BenchConfig.quick_config(args.out, args.seed) if args.quick else BenchConfig(out=args.out, seed=args.seed)
    if args.only:
        wanted = tuple(s.strip() for s in args.only.split(",") if s.strip())
        unknown = [s for s in wanted if s not in cfg.sections]
        if unknown:
            print(f"htdata bench: error: unknown section(s) {unknown}; known: {list(cfg.sections)}", file=sys.stderr)
            return 2
        cfg.sections = wanted
    try:
        results = run_bench(cfg, command="htdata bench " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["bench"]
                            else "htdata bench", progress=not args.quiet)
    except ValueError as exc:
        print(f"htdata bench: error: {exc}", file=sys.stderr)
        return 2
    if results["errors"]:
        for name, msg in results["errors"].items():
            print(f"htdata bench: section {name} failed: {msg}", file=sys.stderr)
        return 1
    print(f"htdata bench: {cfg.out / 'REPORT.md'} ({results['seconds']:.0f} s)", file=sys.stderr)
    return 0
