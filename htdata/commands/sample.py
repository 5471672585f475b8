"""`htdata sample OUT`: write the synthetic raw corpus in the source formats (htdata/synthetic/corpus.py)."""

from __future__ import annotations

import argparse
import json
import sys
import time

from htdata.synthetic.corpus import (
    COMPLETE_MARKER,
    FORMATS,
    SCALES,
    CorpusConfig,
    corpus_complete,
    plan_corpus,
    write_corpus,
)
from htdata.synthetic.rawglove import CLIPS, write_rawglove

EPILOG = """\
Layout written under OUT:
  opentouch/<scene>.hdf5 + annotations.csv      right hand, 16x16, inverted 0..3072, 30 fps
  touchanything/<Scene>/<task>/<traj>/ + split.json   both hands, 21x21, chest.mp4 640x480
  native/<recording>/                            100 Hz tactile, 30 Hz video, clock offset
With --raw-glove, only OUT/rawglove/ (not part of the default corpus):
  rawglove/<clip>/ + layouts/ + truth.json       two-hand 32x32 raw-count knit glove, float16
                                                 counts, glove only, with ground truth (it copies
                                                 a real knit glove's facts: docs/INGEST.md)
  htdata sample data/raw --raw-glove
  htdata ingest --pipeline native --layouts data/raw/rawglove/layouts data/raw/rawglove OUT
Same --seed -> identical tactile arrays and JPEG bytes. OUT/.complete (written last) names
the seed, scale and formats of a finished corpus; --reuse keeps such a corpus and
rewrites anything else (a corpus cut short, or one of another seed).

With --mispair-rgb, the same corpus with every episode's video taken from another episode:
a broken control (make train-smoke-mispaired), marked as such in OUT/.complete. Two more keep
each episode's own world: --rgb-lag-frames K (video K frames behind the glove; make
train-smoke-lagged) and --reverse-rgb (each video played backwards; make train-smoke-reversed).

Examples:
  htdata sample data/raw --scale small
  htdata sample data/raw --seed 1 --reuse
  htdata sample runs/smoke_mispaired/raw --mispair-rgb
  htdata sample runs/smoke_lagged/raw --rgb-lag-frames 6
"""


def _formats(text: str) -> tuple[str, ...]:
    items = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in items if s not in FORMATS]
    if bad or not items:
        raise argparse.ArgumentTypeError(f"formats must be a comma list of {','.join(FORMATS)}, got {text!r}")
    return items


def episode_frames_arg(text: str) -> tuple[int, int]:
    """"N" or "LO,HI": video frames per episode."""
    try:
        parts = [int(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2) or not 2 <= parts[0] <= parts[-1] <= 100_000:
        raise argparse.ArgumentTypeError(f"--episode-frames takes N or LO,HI with 2 <= LO <= HI <= 100000, "
                                         f"got {text!r}")
    return parts[0], parts[-1]


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("out", help="output folder (created if missing)")
    parser.add_argument("--seed", type=int, default=0, help="corpus seed (default 0)")
    parser.add_argument("--scale", choices=SCALES, default="small",
                        help="small: ~50 episodes, every task >= 3 episodes (default); tiny: a few episodes for tests; "
                             "medium: 3x small (~140 episodes, ~9k frames: the ingest benchmark's worker scaling)")
    parser.add_argument("--formats", type=_formats, default=FORMATS,
                        help=f"comma list of formats to write (default {','.join(FORMATS)})")
    parser.add_argument("--episode-frames", type=episode_frames_arg, default=None, metavar="N|LO,HI",
                        help="video frames per episode (drawn in LO..HI per episode) instead of the scale's "
                             "~40-90; same episodes otherwise (e.g. 300,330: the driver bench's long episodes). "
                             "Without it the corpus is byte-identical to earlier ones")
    parser.add_argument("--overwrite", action="store_true", help="replace existing OUT/<format> folders")
    parser.add_argument("--reuse", action="store_true",
                        help=f"exit 0 without writing if OUT holds a finished corpus ({COMPLETE_MARKER}) of the "
                             "same seed, scale and formats; otherwise write it, replacing OUT/<format> folders")
    parser.add_argument("--raw-glove", action="store_true",
                        help="write only OUT/rawglove: the realistic raw-count glove (5 glove-only clips, "
                             "1530 frames, ~6 MB) with its layouts and ground truth")
    parser.add_argument("--mispair-rgb", action="store_true",
                        help="a broken control corpus: every episode's video shows another episode (of another "
                             "task, each frame at a random moment of it), so RGB and touch are mis-paired as a "
                             "pipeline that mixed up episodes would store them; for proving a trainer's checks "
                             "catch that (make train-smoke-mispaired). Never for training")
    parser.add_argument("--rgb-lag-frames", type=int, default=0, metavar="K",
                        help="a broken control corpus: every video lags its glove by K video frames (frame i "
                             "shows the moment K frames earlier), as an uncorrected clock offset would store "
                             "it (make train-smoke-lagged). Never for training")
    parser.add_argument("--reverse-rgb", action="store_true",
                        help="a broken control corpus: every episode's video played backwards (make "
                             "train-smoke-reversed). Never for training")
    parser.add_argument("--dry-run", action="store_true", help="print the planned episodes and exit")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true",
                        help="print the summary as JSON (default: a line per format and the next command)")


def run(args: argparse.Namespace) -> int:
    cfg = CorpusConfig(out=args.out, seed=args.seed, scale=args.scale, formats=tuple(args.formats),
                       overwrite=args.overwrite, progress=not args.quiet, mispair_rgb=args.mispair_rgb,
                       rgb_lag_frames=args.rgb_lag_frames, reverse_rgb=args.reverse_rgb,
                       episode_frames=getattr(args, "episode_frames", None))
    if getattr(args, "raw_glove", False):
        return _raw_glove(args)
    try:
        cfg.validate()
        if args.dry_run:
            for ep in plan_corpus(cfg):
                print(f"{ep.fmt}\t{ep.name}\t{ep.spec.task}\t{ep.spec.scene}\t{ep.spec.n_frames}\t"
                      f"{','.join(ep.spec.hands)}\t{ep.spec.timing}")
            return 0
        if args.reuse:
            if corpus_complete(cfg):
                print(f"htdata sample: {cfg.out} holds the finished corpus (seed {cfg.seed}, scale {cfg.scale}); "
                      "reused", file=sys.stderr)
                return 0
            cfg.overwrite = True
        t0 = time.perf_counter()
        summary = write_corpus(cfg)
    except (ValueError, FileExistsError) as exc:
        print(f"htdata sample: error: {exc}", file=sys.stderr)
        return 2
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    summary["out"] = str(cfg.out)
    print(json.dumps(summary, indent=1) if args.json else "\n".join(corpus_lines(summary)))
    return 0


def corpus_lines(summary: dict) -> list[str]:
    """What was written, a line per format, and the command that ingests it."""
    formats = [f for f in FORMATS if isinstance(summary.get(f), dict)]
    out = summary["out"]
    lines = [f"wrote {out} in {summary['seconds']:.0f} s:"]
    lines += [f"  {f:<14} {summary[f]['episodes']:>4} episodes {summary[f]['frames']:>6} frames  -> {out}/{f}"
              for f in formats]
    pipes = " ".join(f"--pipeline {f}={out}/{f}" for f in formats)
    lines.append(f"next: htdata ingest {pipes} DATASET   (then: htdata validate DATASET)")
    return lines


def _raw_glove(args: argparse.Namespace) -> int:
    """`htdata sample OUT --raw-glove`: OUT/rawglove only."""
    from pathlib import Path


    target = Path(args.out) / "rawglove"
    if args.dry_run:
        for task, n, start in CLIPS:
            print(f"rawglove\t{task}\t{n}\t{start}\tleft,right")
        return 0
    if target.exists() and any(target.iterdir()):
        if not (args.overwrite or args.reuse):
            print(f"htdata sample: error: {target} exists and is not empty; pass --overwrite to replace it",
                  file=sys.stderr)
            return 2
        import shutil
        shutil.rmtree(target)
    summary = write_rawglove(target, seed=args.seed)
    summary["out"] = str(target)
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    print(f"wrote {target}: {summary['clips']} glove-only clips, {summary['frames']} frames, layouts and truth.json\n"
          f"next: htdata ingest --pipeline native --layouts {target}/layouts {target} DATASET")
    return 0
