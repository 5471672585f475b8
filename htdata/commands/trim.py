"""`htdata trim DATASET EPISODE --frames A:B [--dry-run]`: keep frames A..B-1 of one episode, as a new version."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata import curate
from htdata.commands.rm import report
from htdata.lock import DatasetLocked


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = curate.__doc__
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("episode", help="episode id")
    parser.add_argument("--frames", required=True, metavar="A:B",
                        help="frames KEPT, Python slice (B exclusive; '10:' keeps 10 to the end); "
                             "kept frames are renumbered from 0, each sample keeps its source time")
    parser.add_argument("--dry-run", action="store_true", help="print what would change, write nothing")


def run(args: argparse.Namespace) -> int:
    command = f"htdata trim {args.episode} --frames {args.frames}"
    try:
        edit, manifest = curate.trim_episode(args.dataset, args.episode, args.frames, args.dry_run, command)
    except (curate.NoSuchEpisode, DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata trim: error: {exc}", file=sys.stderr)
        return 2
    report(edit, manifest, args.dry_run)
    return 0
