"""`htdata gc DATASET [--keep-versions K] [--retention 7d [--force]] [--dry-run]`: delete old versions and
unlisted shards, never inside the retention window."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.curate import gc
from htdata.store.lock import DatasetLocked

EPILOG = """\
Every write makes a new version and old versions keep their files; gc frees the disk. It keeps
the newest K versions (default 1: only the current one) and, whatever K says, every version
superseded less than --retention ago (default 7 days, as Delta Lake's VACUUM): a training job
still reading an older version keeps working. Outside the window it deletes the other versions'
manifests (leaving a tombstone, so a reader of a collected version gets one clear error naming
the gc), then every shard no kept version lists and unreferenced that long (also leftovers of an
interrupted write), and stats cache entries no kept episode uses. The current version's files are
never deleted; a gc killed half-way is finished by the next one. A retention below 1h needs
--force: readers of the versions it collects then fail.

Examples:
  htdata gc data/dataset --dry-run                   # what would go, what the 7-day window keeps
  htdata gc data/dataset --keep-versions 3
  htdata gc data/dataset --retention 0 --force       # only when no job reads an old version
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--keep-versions", type=int, default=1, metavar="K",
                        help="newest versions kept whatever their age (default 1: only the current one)")
    parser.add_argument("--retention", default=gc.format_duration(gc.DEFAULT_RETENTION_S), metavar="DURATION",
                        help="delete a version only once it has been superseded this long, a shard only once "
                             "unreferenced this long (default 7d; units s, m, h, d; below 1h needs --force)")
    parser.add_argument("--force", action="store_true",
                        help="allow a retention below 1h: readers of a collected version then fail "
                             "(VersionCollected)")
    parser.add_argument("--dry-run", action="store_true",
                        help="list what would be deleted and what the retention window keeps; delete nothing")


def run(args: argparse.Namespace) -> int:
    command = f"htdata gc --keep-versions {args.keep_versions} --retention {args.retention}"
    try:
        retention = gc.parse_duration(args.retention)
        plan = gc.collect(args.dataset, args.keep_versions, args.dry_run, command, retention, args.force)
    except (DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata gc: error: {exc}", file=sys.stderr)
        return 2
    for line in plan.lines(args.dry_run):
        print(line)
    return 0
