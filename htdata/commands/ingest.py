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
one); the dataset's manifest records the effective settings. Cells outside
every block of a layout whose raw values move (range above 12 x the glove's
frame-to-frame noise + 3 x its slow rest wander: htdata/glove/activity.py) are listed per episode and hand on
stderr, in the episode record (`unmapped_moving`) and in the report: add
them to a block or list them in the layout's `unused_cells`.
"""

from __future__ import annotations

import argparse
import sys

from htdata.errors import HtdataError
from htdata.glove.activity import unmapped_warning
from htdata.glove.layouts import LAYOUTS_ENV
from htdata.ingest import ingest, parse_sources
from htdata.ingest.executors import UnitFailed
from htdata.ingest.run import failure_line
from htdata.settings import aim_settings
from htdata.store.lock import DatasetLocked
from htdata.workers import usable_cores

EPILOG = """\
A pipeline says how to read one source format: a shipped name (`htdata pipelines list`:
native, opentouch, touchanything) or your own .toml (`htdata pipelines show NAME` prints one
to copy). `--set key=value` changes one setting without copying the file.
Ingesting into an existing dataset appends, as a new version: unchanged episodes are kept,
changed inputs are re-ingested, edited labels updated; episodes whose source is gone are kept
(`htdata rm` removes them). An interrupted ingest resumes where it stopped. Failures (file,
episode, frame) are listed on stderr and in OUT/reports/ingest.json; exit 1 when an episode
failed (unless --allow-failures), 2 for a usage error, 3 when a work unit kept failing.
A raw-count glove (layout value.max > 1) that the pipeline leaves without a [normalise.<layout>]
table gets its rest from the glove: pooled over the run's recordings of it when there are 3 or
more (an append reuses the dataset's), each recording's own otherwise; the ingest notes which
(docs/INGEST.md "The glove's own rest").
Defaults: one worker per CPU, the process pool, 1 retry.

Examples:
  htdata ingest --pipeline opentouch data/raw/opentouch data/dataset
  htdata ingest --pipeline opentouch=data/raw/opentouch --pipeline touchanything=data/raw/touchanything data/dataset
  # no tactile_<hand>.exr maps, only raw rows htdata's readers render them from (~25% fewer bytes/frame;
  # default "auto": a new dataset stores its maps, an append keeps the dataset's choice)
  htdata ingest --pipeline opentouch --set tactile.maps=raw data/raw/opentouch data/dataset_raw
"""

# what the CLI says after Ctrl-C (htdata/cli.py)
INTERRUPTED = ("run the same command again to resume: finished work units are kept, and the re-run writes what "
               "an uninterrupted run would have")


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("--pipeline", action="append", required=True, metavar="PIPELINE[=SRC]",
                        help="a shipped pipeline name (htdata pipelines list) or a .toml path; repeat for several sources")
    parser.add_argument("paths", nargs="+", metavar="SRC... OUT",
                        help="one SRC per --pipeline (unless given as PIPELINE=SRC), then OUT")
    parser.add_argument("--set", action="append", default=[], dest="settings", metavar="[PIPELINE:]KEY=VALUE",
                        help="override a pipeline setting, e.g. adapter.params.annotations=labels.csv or "
                             "normalise.out_of_range=fail (repeatable; validated like the TOML)")
    parser.add_argument("--layouts", action="append", default=[], metavar="DIR",
                        help=f"folder of glove layout JSONs searched for layout ids (repeatable; before "
                             f"${LAYOUTS_ENV} and the shipped layouts)")
    parser.add_argument("--workers", type=int, default=None,
                        help=f"worker processes (default: the cores this process may use, {usable_cores()} here); "
                             f"0 = run units in this process (debugging); with --executor ray, a local Ray's CPUs")
    parser.add_argument("--executor", choices=("process", "ray"), default="process",
                        help="process (default): local pool, the progress bar advances per finished episode; "
                             "ray: one Ray task per work unit, the bar advances per finished unit")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join (with --executor ray): HOST:PORT of the head as `ray start "
                             "--head` prints it, 'auto' or ray://HOST:PORT; every node must see SRC and OUT at "
                             "the same paths (docs/USAGE.md, Scale-out). Default: a local Ray")
    parser.add_argument("--retries", type=int, default=1, help="retries of a unit that raised (default 1)")
    parser.add_argument("--allow-failures", action="store_true", help="exit 0 even if some episodes failed")
    parser.add_argument("--verify-sources", action="store_true",
                        help="refuse (fail the episode of) a source file whose sha256 differs from a checksum "
                             "list beside the recordings (SHA256SUMS or *.sha256, sha256sum format) or that no "
                             "list covers; without it a mismatch is a warning note. Every episode record keeps "
                             "its source files' sha256 either way")
    parser.add_argument("--quiet", action="store_true",
                        help="hide the progress bar (stderr: episodes done, frames/s)")


def run(args: argparse.Namespace) -> int:
    try:
        sources, out = parse_sources(args.pipeline, args.paths)
        apply_settings(sources, args.settings)
        report = ingest(sources, out, workers=args.workers, executor=args.executor, address=args.address,
                        retries=args.retries, progress=not args.quiet, layout_dirs=tuple(args.layouts),
                        command="htdata ingest " + " ".join(sys.argv[2:]), verify_sources=args.verify_sources)
    # one line, no traceback: LayoutNotFound is a FileNotFoundError; a source folder discovery cannot read keeps
    # its OSError type (ingest.plan.discover_sources); a full disk is the CLI's own line (htdata/cli.py)
    except (HtdataError, ValueError, FileNotFoundError, PermissionError, NotADirectoryError, DatasetLocked) as e:
        print(f"htdata ingest: error: {e}", file=sys.stderr)
        return 2
    except UnitFailed as e:
        print(f"htdata ingest: error: {e}", file=sys.stderr)
        return 3
    n_fail = len(report["failures"])
    for f in report["failures"]:
        print(f"FAILED {failure_line(f)}", file=sys.stderr)
    for eid, warnings in report.get("episode_warnings", {}).items():
        for warning in warnings:            # not only in the episode record: out-of-range values are news
            print(f"episode {eid}: {warning}", file=sys.stderr)
    for note in report["notes"]:
        print(f"note: {note}", file=sys.stderr)
    for episode_id, hands in report.get("unmapped_moving", {}).items():
        for hand, entry in hands.items():
            print(unmapped_warning(f"episode {episode_id}", hand, entry["layout"], entry), file=sys.stderr)
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
    mine = aim_settings(settings, sorted({s.pipeline.name for s in sources}))
    for source in sources:
        if mine[source.pipeline.name]:
            source.pipeline = source.pipeline.with_overrides(mine[source.pipeline.name])
