"""Crash-safe file writes and streamed checksums: below every package, for every writer.

A write goes to a temp file in the same directory, is fsynced and renamed
over the target (then the directory is fsynced), so readers and a re-run
after a crash see the old file or the new one, never half of one. Files get
the mode open() would give (0666 & ~umask), not mkstemp's 0600: a dataset
and a benchmark's results are shared data.

A file that must never be replaced (a shard, a version file, the writer lock)
is created exclusively instead: written whole to a temp file, fsynced, then
hard-linked to its name, which fails if the name exists (`link_exclusive`,
`write_bytes_exclusive`): the one "create it complete or not at all" of the
project. The store adds what needs its URLs (htdata/store/fsutil.py).
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


def link_exclusive(temp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Give the finished file `temp` the name `path` (a hard link: atomic, FileExistsError when `path` exists,
    never a replacement), then remove `temp` whatever happened."""
    try:
        os.link(temp, path)
    finally:
        try:
            Path(temp).unlink(missing_ok=True)
        except OSError:
            pass    # a read-only folder: the caller's error matters more


def write_bytes_exclusive(path: str | os.PathLike, data: bytes) -> None:
    """`data` as a new file `path`, complete when it appears (temp + fsync + `link_exclusive`).

    Raises:
        FileExistsError: `path` exists (nothing is changed).
        OSError: the temp file could not be written (a full disk, a read-only folder); no temp is left.
    """
    path = Path(path)
    temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(temp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        try:
            temp.unlink(missing_ok=True)
        except OSError:
            pass
        raise
    link_exclusive(temp, path)


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
