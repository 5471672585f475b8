"""`htdata preview DATASET OUT.png`: a contact sheet of one episode (RGB | left | right tactile)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.inspect import preview


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = preview.__doc__
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("out", type=Path, metavar="OUT.png", help="contact sheet to write")
    parser.add_argument("--episode", default=None, metavar="ID",
                        help="episode id (default: the two-handed episode with the most contact)")
    parser.add_argument("--frames", type=int, default=6, metavar="N",
                        help="rows: N frames evenly spaced over the episode (default 6)")
    parser.add_argument("--contrast", choices=preview.CONTRASTS, default="fixed",
                        help="fixed: colour scale 0..1 (default); quantile: 0..p99 of the dataset's positive "
                             "taxel values, so faint contact shows (uses `htdata stats`, cached)")


def run(args: argparse.Namespace) -> int:
    try:
        out = preview.write_preview(args.dataset, args.out, episode=args.episode, frames=args.frames,
                                     contrast=args.contrast)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"htdata preview: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0
