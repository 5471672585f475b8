"""`htdata gc DATASET [--keep-versions K] [--dry-run]`: delete old versions and unlisted shards."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata import gc
from htdata.lock import DatasetLocked


EPILOG = """\
Every write makes a new version and old versions keep their files; gc frees the disk. It keeps
the newest K versions (default 1: only the current one), deletes the others' manifests, then
every shard file no kept version lists (also leftovers of an interrupted write) and stats cache
entries no kept episode uses. The current version's shards are never deleted; a gc that is
killed half-way is finished by the next one.

Examples:
  htdata gc data/dataset --dry-run
  htdata gc data/dataset --keep-versions 3
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--keep-versions", type=int, default=1, metavar="K",
                        help="newest versions kept (default 1: only the current one)")
    parser.add_argument("--dry-run", action="store_true", help="list what would be deleted, delete nothing")


def run(args: argparse.Namespace) -> int:
    try:
        plan = gc.collect(args.dataset, args.keep_versions, args.dry_run, f"htdata gc --keep-versions {args.keep_versions}")
    except (DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata gc: error: {exc}", file=sys.stderr)
        return 2
    for line in plan.lines(args.dry_run):
        print(line)
    return 0
