"""`htdata ingest`: raw recordings -> a committed, sharded dataset (htdata/ingest/).

    htdata ingest --pipeline pipelines/opentouch.toml /raw/opentouch OUT
    htdata ingest --pipeline pipelines/opentouch.toml=/raw/opentouch \\
                  --pipeline pipelines/touchanything.toml=/raw/touchanything OUT
    htdata ingest --pipeline A.toml --pipeline B.toml SRC_A SRC_B OUT
    htdata ingest --layouts ~/my_gloves --pipeline native.toml /raw/native OUT
    htdata ingest --pipeline opentouch --set adapter.params.annotations=labels.tsv /raw/opentouch OUT

Ingesting into an existing dataset APPENDS, as a new version: unchanged
episodes are kept as they are, changed inputs are re-ingested, edited labels
are updated, and episodes whose source is gone are kept (htdata rm removes).
Layout ids are searched in --layouts DIR (repeatable), then $HTDATA_LAYOUTS
(os.pathsep-separated folders), then the shipped layouts; every layout used
is copied into OUT/layouts/. Failures (file/episode/frame) are listed on
stderr and in OUT/reports/ingest.json; the exit code is 1 when some episode
failed (unless --allow-failures), 2 for a usage/plan error, 3 when a work
unit kept failing. `--set [PIPELINE:]dotted.key=value` overrides a pipeline
setting without copying its file (value parsed as TOML, else text; checked
like the file; with several pipelines, prefix the pipeline name to aim at
one); the dataset's manifest records the effective settings.
"""

from __future__ import annotations

import argparse
import os
import sys

from htdata.executors import UnitFailed
from htdata.ingest import ingest, parse_sources
from htdata.layouts import LAYOUTS_ENV
from htdata.lock import DatasetLocked


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = __doc__.split("\n\n")[1]
    parser.add_argument("--pipeline", action="append", required=True, metavar="PIPELINE[=SRC]",
                        help="pipeline TOML (or a name in pipelines/); repeat for a multi-source dataset")
    parser.add_argument("paths", nargs="+", metavar="SRC... OUT",
                        help="one SRC per --pipeline (unless given as PIPELINE=SRC), then OUT")
    parser.add_argument("--set", action="append", default=[], dest="settings", metavar="[PIPELINE:]KEY=VALUE",
                        help="override a pipeline setting, e.g. adapter.params.annotations=labels.csv or "
                             "normalise.out_of_range=fail (repeatable; validated like the TOML)")
    parser.add_argument("--layouts", action="append", default=[], metavar="DIR",
                        help=f"folder of glove layout JSONs searched for layout ids (repeatable; before "
                             f"${LAYOUTS_ENV} and the shipped layouts)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                        help="worker processes (default: CPUs); 0 = run units in this process (debugging)")
    parser.add_argument("--executor", choices=("process", "ray"), default="process",
                        help="process: local pool, the progress bar advances per finished episode; "
                             "ray: one Ray task per work unit, the bar advances per finished unit")
    parser.add_argument("--address", default=None, help="Ray cluster address (with --executor ray)")
    parser.add_argument("--retries", type=int, default=1, help="retries of a unit that raised (default 1)")
    parser.add_argument("--allow-failures", action="store_true", help="exit 0 even if some episodes failed")
    parser.add_argument("--quiet", action="store_true",
                        help="hide the progress bar (stderr: episodes done, frames/s)")


def run(args: argparse.Namespace) -> int:
    try:
        sources, out = parse_sources(args.pipeline, args.paths)
        apply_settings(sources, args.settings)
        report = ingest(sources, out, workers=args.workers, executor=args.executor, address=args.address,
                        retries=args.retries, progress=not args.quiet, layout_dirs=tuple(args.layouts),
                        command="htdata ingest " + " ".join(sys.argv[2:]))
    except (ValueError, FileNotFoundError, DatasetLocked) as e:   # LayoutNotFound is a FileNotFoundError: one line, no traceback
        print(f"htdata ingest: error: {e}", file=sys.stderr)
        return 2
    except UnitFailed as e:
        print(f"htdata ingest: error: {e}", file=sys.stderr)
        return 3
    n_fail = len(report["failures"])
    for f in report["failures"]:
        episode = f" [{f['episode_id']}]" if f["episode_id"] is not None else ""
        frame = f" frame {f['frame']}" if f["frame"] is not None else ""
        print(f"FAILED {f['file']}{episode}{frame}: {f['error']}", file=sys.stderr)
    for eid, warnings in report.get("episode_warnings", {}).items():
        for warning in warnings:            # not only in the episode record: out-of-range values are news
            print(f"episode {eid}: {warning}", file=sys.stderr)
    for note in report["notes"]:
        print(f"note: {note}", file=sys.stderr)
    print(f"ingested {report['episodes_ingested']}/{report['episodes_planned']} episodes, "
          f"{report['samples']} samples ({sum(report['rgb_only_samples'].values())} RGB-only), "
          f"{len(report['dropped_frames'])} frames unpaired, {n_fail} failures "
          f"({report['units_resumed']} of {report['units']} units resumed); unchanged "
          f"{report['episodes_unchanged']}, relabelled {len(report['episodes_relabelled'])}, replaced "
          f"{len(report['episodes_replaced'])} -> {out} version {report['version']}", file=sys.stderr)
    if n_fail and not args.allow_failures:
        return 1
    return 0


def apply_settings(sources, settings: list[str]) -> None:
    """Apply `--set [PIPELINE:]key=value` overrides to the sources' pipelines (in place, validated)."""
    names = {s.pipeline.name for s in sources}
    aimed: dict[str | None, list[str]] = {}
    for item in settings:
        key = item.partition("=")[0]
        target, sep, _ = key.partition(":")
        if sep:
            if target not in names:
                raise ValueError(f"--set {item}: no pipeline named {target!r} (pipelines: {sorted(names)})")
            aimed.setdefault(target, []).append(item[len(target) + 1:])
        else:
            aimed.setdefault(None, []).append(item)
    for source in sources:
        mine = aimed.get(None, []) + aimed.get(source.pipeline.name, [])
        if mine:
            source.pipeline = source.pipeline.with_overrides(mine)
