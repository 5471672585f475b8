"""`htdata validate DATASET [--split NAME] [--deep]`: print the verdict, write the JSON report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata import validate
from htdata.commands.outputs import output_path
from htdata.commands.version_arg import version_arg
from htdata.format.table import REPORTS_DIR, VALIDATE_REPORT
from htdata.store.writable import symlinked_folder

EPILOG = """\
Checks, each a section of the report with every failure named by shard / sample / episode / frame:
  structure  manifest, episode records and sample JSON against the schemas; every shard present
             with its sha256 and size; sample counts; frames 0..n-1 in order per episode
  content    decodes every sample (--deep) or a seeded 5% plus each episode's first frame:
             RGB 224x224x3; tactile maps 224x224 EXR of the dataset's pixel type (float, or half
             when every glove's resolution allows it), finite, in [0,1], zero where the glove
             has no sensor
  time       RGB timestamps increasing; RGB-glove skew within the sync tolerance; gaps and
             fps deviations are warnings
  sensors    (warnings) regions that never change, saturated values, all-zero hands
  splits     (--split NAME) parts disjoint and complete, OOD tasks only in ood, no identical
             frame in two parts (a NAME the version lacks is refused first: nothing validated)
The report is written to DATASET/reports/validate.json (never through a symlinked reports/:
refused, pass --json). Exit 0 when every check passes
(warnings allowed), 1 otherwise. A folder that is not a dataset (no dataset.json) gets one
FAIL line and nothing is written into it.

Examples:
  htdata validate data/dataset
  htdata validate data/dataset --split main --deep
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--split", default=None, metavar="NAME", help="also check split NAME of that version")
    parser.add_argument("--version", type=version_arg, default=None, metavar="N",
                        help="validate version N (htdata log lists them; default: the current version)")
    parser.add_argument("--deep", action="store_true", help="decode every sample (default: a seeded sample)")
    parser.add_argument("--sample-frac", type=float, default=0.05,
                        help="fraction of samples decoded without --deep (default 0.05)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the content sample")
    parser.add_argument("--json", type=Path, default=None, metavar="REPORT",
                        help=f"report path (default DATASET/{VALIDATE_REPORT})")
    parser.add_argument("--workers", type=int, default=None,
                        help="processes over shards (default: the cores this process may use with --deep, else "
                             "none); 0 or 1 = check in this process")


def run(args: argparse.Namespace) -> int:
    refused = symlinked_folder(args.dataset, REPORTS_DIR) if args.json is None else None
    if refused:      # checked first: the report would be written outside the dataset
        print(f"htdata validate: error: {refused} (or pass --json REPORT)", file=sys.stderr)
        return 2
    try:
        report = validate.validate_dataset(args.dataset, split=args.split, deep=args.deep,
                                           sample_frac=args.sample_frac, seed=args.seed, workers=args.workers,
                                           version=args.version)
    except ValueError as exc:
        print(f"htdata validate: error: {exc}", file=sys.stderr)
        return 2
    out = args.json or Path(args.dataset) / VALIDATE_REPORT
    missing = _no_dataset(report)
    if missing is not None:      # not a dataset (or no such version): its one line, and nothing written into it
        print(f"htdata validate: FAIL manifest_missing: {missing['message']}", file=sys.stderr)
        if args.json is not None:
            validate.write_report(report, output_path(args.json, "validate"))
        return 1
    print(validate.format_report(report))
    if args.json is None and not Path(args.dataset).is_dir():
        print(f"htdata validate: {args.dataset} is not a directory: no report written", file=sys.stderr)
        return 1
    try:
        validate.write_report(report, output_path(out, "validate") if args.json is not None else out)
        print(f"report: {out}")
    except (OSError, ValueError) as exc:
        print(f"htdata validate: error: cannot write report {out}: {exc}", file=sys.stderr)
        if args.json is not None:   # the report asked for is not there: not a success, whatever the verdict
            return 2
    return 0 if report["ok"] else 1


def _no_dataset(report: dict) -> dict | None:
    """The manifest_missing failure when it is the report's only finding (nothing else could be checked)."""
    failures = report["checks"]["structure"]["failures"]
    if len(failures) == 1 and failures[0]["what"] == "manifest_missing":
        return failures[0]
    return None
