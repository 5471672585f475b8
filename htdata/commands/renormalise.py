"""`htdata renormalise DATASET --pipeline P [--set K=V ...] [--episode ID_OR_GLOB ...] [--force] [--dry-run]`.

New maps from the raw glove rows stored in the dataset, under the pipeline's
calibrations, as a new version (the sources are not read). Example: a glove
recalibrated with a rest-window baseline and a noise floor:

    htdata renormalise DATA/dataset --pipeline pipelines/native.toml \\
        --set normalise.opentouch_right_16x16.baseline=rest_window \\
        --set normalise.opentouch_right_16x16.noise_k=3 --dry-run
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.curate import renormalise
from htdata.ingest.pipeline import load_pipeline
from htdata.store.episodeids import NoSuchEpisode
from htdata.store.lock import DatasetLocked

EPILOG = """\
A glove recalibrated after recording needs no sources: every sample stores its raw glove rows,
so new maps are computed from them under the pipeline's [normalise] settings and written as a
new version (RGB and raw rows are copied unchanged). Episodes whose calibration does not change
are reused (--force recomputes them, byte for byte the same). Per-episode fits (baseline, noise
floor) are made from the stored raw rows as the ingest makes them (the rest window's first frames;
the whole episode for quietest / percentile / drift). Defaults: every episode.

Examples:
  htdata renormalise data/dataset --pipeline native --set normalise.opentouch_right_16x16.noise_k=3 --dry-run
  htdata renormalise data/dataset --pipeline my_gloves.toml --episode 'nat-*'
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("dataset", type=Path, help="committed dataset directory (format 3: raw rows stored)")
    parser.add_argument("--episode", dest="episodes", action="append", default=[], metavar="ID_OR_GLOB",
                        help="renormalise only these episodes (id or quoted shell glob; repeatable; default: all)")
    parser.add_argument("--pipeline", required=True, metavar="P",
                        help="pipeline TOML (or shipped name) whose [normalise] tables give the new calibrations")
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="override a pipeline setting, e.g. normalise.LAYOUT.noise_k=3 (repeatable)")
    parser.add_argument("--force", action="store_true",
                        help="also recompute episodes whose calibration is unchanged (maps come out byte for byte)")
    parser.add_argument("--dry-run", action="store_true", help="print what would change, write nothing")


def run(args: argparse.Namespace) -> int:
    command = " ".join(["htdata renormalise", "--pipeline", args.pipeline,
                        *[f"--set {s}" for s in args.settings], *[f"--episode {e}" for e in args.episodes], *(["--force"] if args.force else [])])
    try:
        pipeline = load_pipeline(args.pipeline)
        if args.settings:
            pipeline = pipeline.with_overrides(args.settings)
        plan, manifest = renormalise.renormalise(args.dataset, pipeline.normalise_settings(), args.episodes,
                                                 args.dry_run, args.force, command)
    except (NoSuchEpisode, DatasetLocked, FileNotFoundError, ValueError) as exc:
        print(f"htdata renormalise: error: {exc}", file=sys.stderr)
        return 2
    for line in plan.notes:                  # as the ingest notes: which glove rest a raw-count glove got
        print(f"note: {line}", file=sys.stderr)
    for lines in plan.warnings.values():     # as the ingest warns: a raw-count glove's rest read as pressure
        for line in lines:
            print(line, file=sys.stderr)
    for line in plan.lines(args.dry_run):
        print(line)
    if manifest is not None:
        print(f"version {manifest['version']} (parent {manifest['parent']}): {manifest['counts']['episodes']} "
              f"episodes, {manifest['counts']['samples']} frames; the parent stays readable until htdata gc")
    elif not plan.changes and not args.dry_run:
        print(f"nothing changed: version {plan.parent} stays current (every episode already has these "
              f"calibrations; --force recomputes anyway)")
    return 0
