"""`htdata trim DATASET EPISODE --frames A:B [--dry-run]`: keep frames A..B-1 of one episode, as a new version.

`htdata trim DATASET --idle [--min-contact X] [--keep-margin S] [--dry-run]`: drop every episode's idle head
and tail (no contact on any hand) in one new version (htdata/curate/idle.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.commands.rm import report
from htdata.curate import edit as curate_edit
from htdata.curate import idle
from htdata.store.episodeids import NoSuchEpisode
from htdata.store.lock import DatasetLocked
from htdata.store.versions import current_version

EPILOG = """\
Nothing is changed in place: the result is a new version (`htdata log` lists versions, old ones
stay readable until `htdata gc`), planned first and written only then; --dry-run prints the plan.
Only the storage files holding touched episodes are rewritten. Splits carry over (a removed
episode leaves its part). An id or glob that matches nothing is an error listing near matches.
--idle trims, in every episode, the frames before the first and after the last contact of any
hand, keeping --keep-margin seconds (default 0.5) around them. Contact is each glove hand's
contact rule from its calibration (docs/USAGE.md "Contact": with a noise floor, a few taxels
above their floor; without one, any taxel above 0.02); --min-contact X: any taxel above X.
It prints one line per episode, then one summary line per kind of change.

Examples:
  htdata trim data/dataset ot-home_kitchen_p1-demo_19 --frames 10:90 --dry-run
  htdata trim data/dataset --idle
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("episode", nargs="?", default=None, help="episode id (not with --idle)")
    parser.add_argument("--frames", default=None, metavar="A:B",
                        help="frames KEPT, Python slice (B exclusive; '10:' keeps 10 to the end); "
                             "kept frames are renumbered from 0, each sample keeps its source time")
    parser.add_argument("--dry-run", action="store_true", help="print what would change, write nothing")
    parser.add_argument("--idle", action="store_true",
                        help="trim every episode's head and tail without contact on any hand (see below)")
    parser.add_argument("--min-contact", type=float, default=None, metavar="X",
                        help="with --idle: a frame is in contact when a taxel reads above X (the old rule, e.g. "
                             "0.02); default: each glove hand's contact rule from its calibration "
                             "(at least 3 taxels above their noise floor, or any taxel "
                             "> 0.02 for a calibration without a floor)")
    parser.add_argument("--keep-margin", type=float, default=None, metavar="S",
                        help="with --idle: seconds kept before the first and after the last contact (default 0.5)")


def run(args: argparse.Namespace) -> int:
    if args.idle:
        return run_idle(args)
    if args.episode is None or args.frames is None or args.min_contact is not None or args.keep_margin is not None:
        print("htdata trim: error: give EPISODE and --frames A:B, or --idle (with --min-contact / --keep-margin)",
              file=sys.stderr)
        return 2
    command = f"htdata trim {args.episode} --frames {args.frames}"
    try:
        edit, manifest = curate_edit.trim_episode(args.dataset, args.episode, args.frames, args.dry_run, command)
    except (NoSuchEpisode, DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata trim: error: {exc}", file=sys.stderr)
        return 2
    report(edit, manifest, args.dry_run)
    return 0


def run_idle(args: argparse.Namespace) -> int:
    if args.episode is not None or args.frames is not None:
        print("htdata trim: error: --idle trims every episode: give no EPISODE and no --frames", file=sys.stderr)
        return 2
    cfg = idle.IdleConfig()
    cfg.min_contact = cfg.min_contact if args.min_contact is None else args.min_contact
    cfg.keep_margin_s = cfg.keep_margin_s if args.keep_margin is None else args.keep_margin
    rule = "" if cfg.min_contact is None else f" --min-contact {cfg.min_contact:g}"
    command = f"htdata trim --idle{rule} --keep-margin {cfg.keep_margin_s:g}"
    try:
        cfg.validate()
        cuts, edit, manifest = idle.trim_idle(args.dataset, cfg, args.dry_run, command)
    except (DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata trim: error: {exc}", file=sys.stderr)
        return 2
    for cut in cuts:
        print(cut.line(args.dry_run))
    if edit is None:
        print(f"nothing changed: version {current_version(args.dataset)} stays current "
              f"(no idle head or tail to trim)")
        return 0
    report(edit, manifest, args.dry_run)
    return 0
