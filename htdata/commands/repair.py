"""`htdata repair DATASET [--dry-run]`: rewrite dataset.json from the newest version file (or the reverse)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.store import repair
from htdata.store.lock import DatasetLocked


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = repair.__doc__ + "\nexample:\n  htdata repair data/ds --dry-run   # show what would be rewritten\n"
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
