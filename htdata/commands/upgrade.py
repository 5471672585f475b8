"""`htdata upgrade DATASET [--dry-run]`: the current version stored again in today's format, as a new version."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.curate.upgrade import upgrade
from htdata.store.lock import DatasetLocked

EPILOG = """\
A dataset an older htdata wrote stays readable as it is, and its next write (ingest, split, rm,
trim, renormalise) stores the new version in today's format anyway. `upgrade` makes that step on
its own, as a new version holding the same episodes, samples, shards and splits: from format 3
(each version its own episodes.jsonl and index.npy, rewritten whole by every write) to format 4
(segments shared between versions, so a write costs what it changes: docs/FORMAT.md). No shard
is read or rewritten; old versions stay readable until `htdata gc`. --dry-run says what it would do.

Examples:
  htdata upgrade data/dataset --dry-run
  htdata upgrade data/dataset
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--dry-run", action="store_true", help="print what would change, write nothing")


def run(args: argparse.Namespace) -> int:
    try:
        plan, manifest = upgrade(args.dataset, args.dry_run, "htdata upgrade")
    except (DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata upgrade: error: {exc}", file=sys.stderr)
        return 2
    for line in plan.lines(args.dry_run):
        print(line)
    if manifest is not None:
        print(f"version {manifest['version']} (parent {manifest['parent']}): format {manifest['format_version']}, "
              f"{len(manifest['segments'])} segments; the parent stays readable until htdata gc")
    return 0
