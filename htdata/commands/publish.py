"""`htdata publish DATASET URL`: upload one consistent snapshot of a dataset to an fsspec URL, verified,
manifest last, never over another dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.errors import HtdataError
from htdata.store.lock import DatasetLocked
from htdata.store.remote import publish_dataset
from htdata.validate.gate import require_valid

EPILOG = """\
What goes up: the current version, pinned when publish starts (a commit made
while it runs is left for the next publish), and every version before it,
with the shards, records and layouts they list. Before anything is written
at URL, publish refuses, in one line:
  - a URL naming no folder (file://, an empty path), or a local folder that
    is DATASET, lies inside it or holds it (symlinks resolved);
  - a folder holding someone's files, another htdata dataset, or a newer
    copy of this one (datasets are told apart by their version files);
  - a version that fails `htdata validate` (its quick check: the first
    failing check is named);
  - a file whose sha256 differs from its manifest's record.
An earlier publish of this dataset at URL is updated: files already there
are read back and kept, only what is missing goes up. Every upload is read
back and its sha256 checked; dataset.json goes up last, so until the end the
URL holds what it held before (nothing on a first publish). Readers open the
URL directly: htdata.open("s3://bucket/ds"). For LeRobot users, see
`htdata export lerobot`.

Examples:
  htdata publish data/dataset s3://bucket/ds
  htdata publish data/dataset s3://bucket/ds        # again after an ingest: only the new files go up
  htdata publish data/dataset file:///mnt/share/ds
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", type=Path, help="committed local dataset directory")
    parser.add_argument("url", help="fsspec URL of the folder to publish into (s3://, gs://, memory://, file://, "
                                    "or a local path)")
    parser.add_argument("--quiet", action="store_true", help="no per-file progress")


def _progress(done: int, total: int, rel: str) -> None:
    print(f"[{done}/{total}] {rel}", file=sys.stderr)


def _validated(quiet: bool):
    def check(root: Path, version: int) -> None:
        if not quiet:
            print(f"validating {'version ' + str(version) if version else root} (quick check) ...", file=sys.stderr)
        require_valid(root, version)
    return check


def run(args: argparse.Namespace) -> int:
    try:
        result = publish_dataset(args.dataset, args.url, on_file=None if args.quiet else _progress,
                                 check=_validated(args.quiet))
    except (HtdataError, DatasetLocked, ValueError, OSError) as exc:
        print(f"htdata publish: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    label = f"version {result.version}" if result.version else "the dataset"
    if not result.files:
        print(f"{result.url} already holds {label}: nothing uploaded ({result.kept} files read back, "
              f"sha256 verified)", file=sys.stderr)
        return 0
    print(f"published {label}: {result.files} files, {result.bytes / 2**20:.1f} MiB to {result.url}, "
          f"{result.kept} already there, in {result.seconds:.1f} s (verified sha256; dataset.json written last)",
          file=sys.stderr)
    return 0
