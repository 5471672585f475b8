"""`htdata merge A B OUT`: one dataset from two, shards linked or copied (sha256-verified), never re-encoded."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.curate import merge
from htdata.store.lock import DatasetLocked


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = merge.__doc__
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("a", type=Path, help="first dataset (its shard names are kept)")
    parser.add_argument("b", type=Path, help="second dataset")
    parser.add_argument("out", type=Path, help="new dataset directory (must be empty or absent)")


def run(args: argparse.Namespace) -> int:
    try:
        report = merge.merge(args.a, args.b, args.out, f"htdata merge {args.a} {args.b} {args.out}")
    except (merge.MergeConflict, DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata merge: error: {exc}", file=sys.stderr)
        return 2
    for line in report.lines():
        print(line)
    print(f"-> {args.out}: version 1, {report.manifest['counts']['episodes']} episodes, "
          f"{report.manifest['counts']['samples']} frames (run htdata split on it)")
    return 0
