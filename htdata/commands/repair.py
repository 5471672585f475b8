"""`htdata repair DATASET [--dry-run]`: rewrite dataset.json from the newest version file (or the reverse)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.store import repair
from htdata.store.lock import DatasetLocked

EPILOG = """\
A dataset's versions/vN.json files are the record of what was committed; dataset.json is a
cache of the newest of them. A missing, truncated or stale dataset.json loses nothing (readers
and writers go by the version files), and repair rewrites it from the newest complete version.
If the newest version file itself is gone or damaged while dataset.json still holds it, repair
restores that file from dataset.json. Nothing else is touched; it takes the writer lock.

Examples:
  htdata repair data/dataset --dry-run     # what would be rewritten, and why
  htdata repair data/dataset
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="dataset directory")
    parser.add_argument("--dry-run", action="store_true", help="print what would be rewritten, write nothing")


def run(args: argparse.Namespace) -> int:
    try:
        plan = repair.repair(args.dataset, args.dry_run, "htdata repair")
    except (DatasetLocked, OSError, ValueError) as exc:
        print(f"htdata repair: error: {exc}", file=sys.stderr)
        return 2
    for line in plan.lines(args.dry_run):
        print(line)
    return 1 if plan.problems else 0
