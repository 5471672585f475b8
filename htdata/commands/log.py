"""`htdata log DATASET`: the versions of a dataset, oldest first (id, time, command, what changed)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from htdata.store.history import log_entries


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = """\
Every write (ingest, split, rm, trim, merge, renormalise) makes a new version, printed as vN
(* = current) with what it added and removed and the command that made it. Old versions stay
readable until `htdata gc`: pass --version 3 (or v3) to stats, validate, card or export, or
htdata.open(path, version=3) in Python.

Examples:
  htdata log data/dataset
  htdata diff data/dataset v1 v2
"""
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--json", action="store_true", help="print the entries as JSON")


def format_entry(e: dict) -> str:
    s = e["summary"]
    mark = "*" if e["current"] else " "
    return (f"{mark} v{e['version']:<4} {e['time']}  +{s.get('episodes_added', 0)}/-{s.get('episodes_removed', 0)}"
            f"/~{s.get('episodes_changed', 0)} episodes  +{s.get('frames_added', 0)}/-{s.get('frames_removed', 0)}"
            f" frames  = {e['episodes']} episodes, {e['samples']} frames  {e['author']}: {e['command']}")


def run(args: argparse.Namespace) -> int:
    try:
        entries = log_entries(args.dataset)
    except (FileNotFoundError, ValueError) as exc:
        print(f"htdata log: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(entries, indent=2))
    elif not entries:
        print(f"{args.dataset}: no version history (written before versions existed); "
              f"the next write makes version 1")
    else:
        print("  version  time                       episodes (+added/-removed/~changed)  frames  ...  command")
        for e in entries:
            print(format_entry(e))
    return 0
