"""Crash-safe file writes and streamed checksums: below every package, for every writer.

A write goes to a temp file in the same directory, is fsynced and renamed
over the target (then the directory is fsynced), so readers and a re-run
after a crash see the old file or the new one, never half of one. Files get
the mode open() would give (0666 & ~umask), not mkstemp's 0600: a dataset
and a benchmark's results are shared data.

The store adds what needs its URLs (htdata/store/fsutil.py `sha256_file`);
the shard writer (htdata/format/shardio.py) links its temp file instead of
renaming it (a finished shard is never replaced) and fsyncs the folder here.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterator

CHUNK = 1 << 20
# mkstemp creates 0600 files; a dataset is shared data, so files get the mode open() would give (0666 & ~umask).
_UMASK = os.umask(0)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK


def fsync_dir(directory: str | os.PathLike) -> None:
    """Make a rename or link inside `directory` durable; a folder that cannot be opened is left alone."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_open(path: str | os.PathLike) -> Iterator[IO[bytes]]:
    """A binary file whose content replaces `path` only when the with-block ends without error.

    For writers that stream (downloads, large files); an exception inside the
    block removes the temp file and leaves `path` as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, FILE_MODE)
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """`data` as the whole content of `path` (atomic_open)."""
    with atomic_open(path) as f:
        f.write(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """`text` (UTF-8) as the whole content of `path` (atomic_open)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike, obj, *, indent: int | None = 2, sort_keys: bool = False) -> None:
    """`obj` as JSON (+ a final newline) as the whole content of `path` (atomic_open)."""
    write_text_atomic(path, json.dumps(obj, indent=indent, sort_keys=sort_keys) + "\n")


def sha256_stream(f: IO[bytes], chunk: int = CHUNK) -> str:
    """Hex sha256 of what is left to read in binary file `f`, read `chunk` bytes at a time."""
    h = hashlib.sha256()
    for block in iter(lambda: f.read(chunk), b""):
        h.update(block)
    return h.hexdigest()
