"""`htdata rm DATASET EPISODE_OR_GLOB... [--dry-run]`: a new version without those episodes."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.curate import edit as curate_edit
from htdata.store.episodeids import NoSuchEpisode
from htdata.store.lock import DatasetLocked

EPILOG = """\
Nothing is changed in place: the result is a new version (`htdata log` lists versions, old ones
stay readable until `htdata gc`), planned first and written only then; --dry-run prints the plan.
Only the storage files holding touched episodes are rewritten. Splits carry over (a removed
episode leaves its part). An id or glob that matches nothing is an error naming it and the number of
episodes, with the ids spelled like it when there are any ("did you mean: ..."); nothing is removed.

Examples:
  htdata rm data/dataset ot-home_kitchen_p1-demo_19 --dry-run
  htdata rm data/dataset 'ta-Office-*'
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("episodes", nargs="+", metavar="EPISODE",
                        help="episode id or shell glob (quote it: 'ot-home_*'); each must match something")
    parser.add_argument("--dry-run", action="store_true", help="print what would change, write nothing")


def run(args: argparse.Namespace) -> int:
    command = "htdata rm " + " ".join(args.episodes)
    try:
        edit, manifest = curate_edit.remove_episodes(args.dataset, args.episodes, args.dry_run, command)
    except (NoSuchEpisode, DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata rm: error: {exc}", file=sys.stderr)
        return 2
    report(edit, manifest, args.dry_run)
    return 0


def report(edit: curate_edit.Edit, manifest: dict | None, dry_run: bool) -> None:
    for line in edit.lines(dry_run):
        print(line)
    if manifest is None and not dry_run:     # as ingest and split: an identical version is not committed
        print(f"nothing changed: version {edit.parent} stays current")
    if manifest is not None:
        print(f"version {manifest['version']} (parent {manifest['parent']}): {manifest['counts']['episodes']} "
              f"episodes, {manifest['counts']['samples']} frames; the parent stays readable until htdata gc")
