"""`htdata diff DATASET A B`: episodes added, removed and changed from version A to version B."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from htdata.commands.version_arg import version_arg
from htdata.store.history import diff_versions

EPILOG = """\
+ added, - removed, ~ changed: same episode id, different record (re-ingested from changed
inputs, trimmed, relabelled); where an episode is stored (shards, sample offsets) is ignored.
Versions are written 3 or v3, as `htdata log` prints them.

Examples:
  htdata diff data/dataset v1 v3
  htdata diff data/dataset 2 3 --json
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("a", type=version_arg, help="older version (htdata log lists them)")
    parser.add_argument("b", type=version_arg, help="newer version")
    parser.add_argument("--json", action="store_true", help="print the diff as JSON")


def run(args: argparse.Namespace) -> int:
    try:
        diff = diff_versions(args.dataset, args.a, args.b)
    except (FileNotFoundError, ValueError) as exc:
        print(f"htdata diff: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(diff, indent=2))
        return 0
    for sign, key in (("+", "added"), ("-", "removed"), ("~", "changed")):
        for eid in diff[key]:
            print(f"{sign} {eid}")
    print(f"v{args.a} -> v{args.b}: {len(diff['added'])} added, {len(diff['removed'])} removed, "
          f"{len(diff['changed'])} changed; frames {diff['frames_before']} -> {diff['frames_after']}")
    return 0
