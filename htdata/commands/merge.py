"""`htdata merge A B OUT`: one dataset from two, shards linked or copied (sha256-verified), never re-encoded."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.commands.outputs import output_path
from htdata.curate import merge
from htdata.store.lock import DatasetLocked

EPILOG = """\
OUT gets every episode of A and B; nothing is re-encoded (shards are hard-linked when A, B and
OUT share a file system, copied otherwise, and each is checked against its sha256). Refused,
with the difference named, when A and B use another canonical hand, another codec, a layout id
with different contents, or one episode id with different content (the same episode with the
same content is kept once). OUT starts at version 1 with no splits: run `htdata split` on it.
Running an interrupted merge again starts it over.

Examples:
  htdata merge data/kitchen data/office data/all
  htdata split data/all --ood-task palm_push --name main
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("a", type=Path, help="first dataset (its shard names are kept)")
    parser.add_argument("b", type=Path, help="second dataset")
    parser.add_argument("out", type=Path, help="new dataset directory (must be empty or absent)")


def run(args: argparse.Namespace) -> int:
    try:
        report = merge.merge(args.a, args.b, output_path(args.out, "merge"), f"htdata merge {args.a} {args.b} {args.out}")
    except (merge.MergeConflict, DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata merge: error: {exc}", file=sys.stderr)
        return 2
    for line in report.lines():
        print(line)
    print(f"-> {args.out}: version 1, {report.manifest['counts']['episodes']} episodes, "
          f"{report.manifest['counts']['samples']} frames (run htdata split on it)")
    return 0
