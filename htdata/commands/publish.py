"""`htdata publish DATASET URL`: upload a committed dataset to an fsspec URL, verified, manifest last."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from htdata.store.remote import publish_dataset

EPILOG = """\
Every file is read back and its sha256 checked; dataset.json goes up last, so
an interrupted upload never leaves a valid-looking dataset at the URL. Readers
open the URL directly: htdata.open("s3://bucket/ds"). For LeRobot users, see
`htdata export lerobot`.

Examples:
  htdata publish data/dataset s3://bucket/ds
  htdata publish data/dataset file:///mnt/share/ds
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", type=Path, help="committed local dataset directory")
    parser.add_argument("url", help="fsspec URL to upload to (s3://, gs://, memory://, file://)")
    parser.add_argument("--quiet", action="store_true", help="no per-file progress")


def _progress(done: int, total: int, rel: str) -> None:
    print(f"[{done}/{total}] {rel}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    try:
        result = publish_dataset(args.dataset, args.url, on_file=None if args.quiet else _progress)
    except (FileNotFoundError, ValueError, OSError) as exc:
        print(f"htdata publish: error: {exc}", file=sys.stderr)
        return 2
    print(f"published {result.files} files, {result.bytes / 2**20:.1f} MiB to {result.url} "
          f"in {result.seconds:.1f} s (verified sha256; dataset.json written last)", file=sys.stderr)
    return 0
