"""The sha256 of a stored file, local or at an fsspec URL (`sha256_file`).

The crash-safe writes and `sha256_stream` live below every package, in
htdata/fileio.py; their old names here (`from htdata.store.fsutil import
atomic_open`) keep working with a DeprecationWarning until htdata/_moved.py's
REMOVED_IN.
"""

from __future__ import annotations

import os

from htdata._moved import moved_name
from htdata.fileio import CHUNK, sha256_stream
from htdata.store import storage


def sha256_file(path: str | os.PathLike, chunk: int = CHUNK) -> str:
    """sha256 of a local file or an fsspec URL."""

    with storage.open_binary(path) as f:
        return sha256_stream(f, chunk)


def __getattr__(name: str):
    return moved_name(__name__, name)
