"""`htdata card DATASET OUT.html [--version N]`: a self-contained dataset card (+ OUT.md and OUT_files/)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.versions_arg import version_arg
from htdata import card


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = card.__doc__
    parser.add_argument("dataset", help="committed dataset directory")
    parser.add_argument("out", type=Path, metavar="OUT.html", help="card to write (OUT.md and OUT_files/ beside it)")
    parser.add_argument("--version", type=version_arg, default=None, metavar="N", help="version (default: current)")


def run(args: argparse.Namespace) -> int:
    try:
        page, md = card.write_card(args.dataset, args.out, version=args.version)
    except (ValueError, FileNotFoundError, KeyError, OSError) as exc:
        print(f"htdata card: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {page} and {md}")
    return 0
