"""`htdata bench`: run every benchmark side by side; write OUT/results.json and OUT/REPORT.md.

Imports inside functions: `run` loads the suite (htdata/benchmarks/suite.py) when the bench runs, so
`htdata bench --help` works on an install without torch (the bench's loader sections need the [bench]
extra); a run without torch is one line naming it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from htdata.commands.sample import episode_frames_arg

NEEDS_TORCH = "htdata bench needs torch (its loader sections time the torch datasets): pip install 'htdata[bench]'"

EPILOG = """\
Sections found through the entry point group htdata.bench_sections (e.g. HandTouch's
"training") run after the built-in ones. A failed section exits 1; the others still report.

Examples:
  htdata bench --out bench            # full: ~6-10 min on 2 cores (make bench)
  htdata bench --quick --out /tmp/b   # tiny sizes (tests)
  htdata bench --only codecs,export   # some sections (installed plugin sections by name too)
  htdata bench --only realglove --real-glove ../shared/real_glove   # the rules on real recordings
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("--out", type=Path, default=Path("bench"), help="output folder (default: bench)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: a smoke run of every section (< 1 min)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sample corpus and of random access")
    parser.add_argument("--only", default=None, metavar="A,B",
                        help="comma-separated sections to run (default: all, discovered ones included)")
    parser.add_argument("--driver-scales", default=None, metavar="A,B",
                        help="section driver: the two sample corpus scales, smaller first (default tiny,medium)")
    parser.add_argument("--driver-episode-frames", type=episode_frames_arg, default=None, metavar="N|LO,HI",
                        help="section driver: episodes of LO..HI frames in both corpora (htdata sample "
                             "--episode-frames), e.g. 300,330 for the projection at real episode lengths")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--real-glove", type=Path, default=None, metavar="DIR",
                        help="real raw-count recordings for section realglove (clips/manifest.jsonl, clips/*.npz, "
                             "layouts/*.json; make bench passes ../shared/real_glove when it exists); without it "
                             "the section says it was not measured")


def run(args: argparse.Namespace) -> int:
    try:
        from htdata.benchmarks.suite import BenchConfig, run_bench
    except ModuleNotFoundError as exc:
        if exc.name != "torch" and not (exc.name or "").startswith("torch."):
            raise
        print(f"htdata bench: error: {NEEDS_TORCH}", file=sys.stderr)
        return 2
    cfg = BenchConfig.quick_config(args.out, args.seed) if args.quick else BenchConfig(out=args.out, seed=args.seed)
    if args.only is not None:
        cfg.sections = tuple(s.strip() for s in args.only.split(",") if s.strip())
    cfg.real_glove = args.real_glove
    if getattr(args, "driver_scales", None):
        cfg.driver_scales = tuple(s.strip() for s in args.driver_scales.split(","))
    if getattr(args, "driver_episode_frames", None):
        cfg.driver_episode_frames = args.driver_episode_frames
    t_start = time.perf_counter()

    def log(message: str) -> None:
        print(f"[bench {time.perf_counter() - t_start:6.1f}s] {message}", file=sys.stderr, flush=True)

    command = "htdata bench " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["bench"] else "htdata bench"
    # a bad option is an ArgumentError: cli.py prints its one line and returns 2
    results = run_bench(cfg, command=command, log=None if args.quiet else log)
    if results["errors"]:
        for name, msg in results["errors"].items():
            print(f"htdata bench: section {name} failed: {msg}", file=sys.stderr)
        return 1
    print(f"htdata bench: {cfg.out / 'REPORT.md'} ({results['seconds']:.0f} s)", file=sys.stderr)
    return 0
