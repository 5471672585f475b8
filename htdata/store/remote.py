"""Remote datasets: publish a committed dataset to an fsspec URL; cache a remote index locally.

`htdata publish DATASET URL` (htdata/commands/publish.py) runs `publish_dataset`,
in this order, and writes nothing at the URL until every check has passed:

1. the destination (store/destination.py): a URL naming no folder, a local
   folder that is, holds or lies inside the dataset (symlinks resolved), a
   folder of someone's files, another dataset, or a newer copy of this one are
   refused with one line;
2. one consistent snapshot (store/publishplan.py): the current version is
   pinned as a reader pins it; a writer committing meanwhile changes nothing
   published;
3. the caller's check of that version (the command runs `htdata validate`'s
   quick validation and refuses with its first failing check);
4. the source's checksums: every file is hashed and compared with the sha256
   its manifest records, before anything is uploaded;
5. what the destination already holds (an earlier publish of this dataset) is
   read back and kept when its sha256 is right: an update only adds;
6. the upload: first the marker `.htdata-publish.json` (the sha256 of each
   version file being published: a resumed publish knows its own folder by
   it), then layouts, shards and records, each read back and its sha256
   checked against the verified source, then the version files after the
   files they list (a version file on a local disk IS a committed version),
   and `dataset.json` LAST. Those small files go up whole: under a temp name,
   read back, renamed. Until the end the URL holds what it held before:
   nothing (no dataset.json) on a first publish, the previous publish on an
   update; a rerun after an interruption uploads only what is missing.

Readers on a URL (`DatasetReader("s3://...")`) keep shard reads ranged
(seek + read on the fsspec file) but fetch index.npy once into a local cache
(HTDATA_CACHE, default ~/.cache/htdata), keyed by the manifest's
index_sha256, and memory-map it from there; a second open downloads nothing.
"""

from __future__ import annotations

import hashlib
import os
import posixpath
import time
import uuid
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.faults import crash_point
from htdata.fileio import atomic_open, sha256_stream
from htdata.format.table import INDEX_FILE, MANIFEST_FILE
from htdata.store import storage
from htdata.store.destination import (
    MARKER,
    TEMP_SUFFIX,
    Destination,
    DestinationRefused,
    check_identity,
    marker_bytes,
    open_destination,
    read_state,
    refuse_overlap,
)
from htdata.store.fsutil import sha256_file
from htdata.store.indexfile import load_index_file
from htdata.store.lock import WriterLock
from htdata.store.publishplan import PinnedDataset, pin_dataset
from htdata.store.storage import cache_dir
from htdata.store.versions import version_manifest_file

CHUNK = 1 << 20
# A caller's check of the pinned version (root, version; 0 = unversioned), raising to refuse the publish.
VersionCheck = Callable[[Path, int], None]


@dataclass
class PublishResult:
    url: str
    version: int        # the version published (0: an unversioned dataset)
    files: int          # files uploaded, dataset.json included when it changed
    bytes: int          # bytes uploaded
    kept: int           # files already at the URL, read back and found right
    seconds: float      # the whole publish: checks, validation, hashing and upload


# -- publish ----------------------------------------------------------------

def upload_file(fs, local: Path, remote: str) -> str:
    """Copy one local file to `remote` (streamed); return the sha256 of the bytes written."""
    parent = posixpath.dirname(remote)
    if parent:
        fs.makedirs(parent, exist_ok=True)
    h = hashlib.sha256()
    with open(local, "rb") as src, fs.open(remote, "wb") as dst:
        for block in iter(lambda: src.read(CHUNK), b""):
            h.update(block)
            dst.write(block)
    return h.hexdigest()


def remote_sha256(fs, remote: str) -> str:
    with fs.open(remote, "rb") as f:
        return sha256_stream(f)


def upload_whole(fs, data: bytes, remote: str) -> None:
    """Put `data` at `remote` whole or not at all: a temp name beside it, read back, then renamed."""
    parent = posixpath.dirname(remote)
    if parent:
        fs.makedirs(parent, exist_ok=True)
    tmp = f"{parent}/.{posixpath.basename(remote)}.{uuid.uuid4().hex[:8]}{TEMP_SUFFIX}"
    fs.pipe_file(tmp, data)
    if remote_sha256(fs, tmp) != hashlib.sha256(data).hexdigest():
        fs.rm(tmp)
        raise IOError(f"{remote}: read-back sha256 differs from what was uploaded")
    fs.mv(tmp, remote)


def verify_sources(pinned: PinnedDataset) -> dict[str, str]:
    """sha256 of every file to publish, checked against its manifest's record; DatasetError on the first
    mismatch (before anything is uploaded)."""
    sums = {}
    for rel, expected in pinned.files:
        local = pinned.root / rel
        sums[rel] = sha256_file(local)
        if expected is not None and sums[rel] != expected:
            raise DatasetError(f"{local}: sha256 differs from the manifest: the local dataset is damaged "
                               f"(run `htdata validate {pinned.root}`); nothing was uploaded")
    return sums


def survey(dest: Destination, pinned: PinnedDataset, sums: dict[str, str]) -> list[str]:
    """The files the destination lacks or holds damaged (read back); refused when a file the records give
    no sha256 for is there with other bytes (whose would be right cannot be told)."""
    fs = dest.fs
    present = {posixpath.relpath(p, dest.base): info.get("size")
               for p, info in fs.find(dest.base, detail=True).items()} if fs.exists(dest.base) else {}
    todo = []
    for rel, expected in pinned.files:
        if rel in present and present[rel] == (pinned.root / rel).stat().st_size \
                and remote_sha256(fs, dest.path(rel)) == sums[rel]:
            continue
        if rel in present and expected is None:
            raise DestinationRefused(f"{dest.url}/{rel}: already there with other bytes than this dataset's, and "
                                     f"no record says which are right; remove it or choose another URL; "
                                     f"nothing was written")
        todo.append(rel)
    return todo


def publish_dataset(local_root: str | os.PathLike, url: str,
                    on_file: Callable[[int, int, str], None] | None = None,
                    check: VersionCheck | None = None) -> PublishResult:
    """Publish the current version of a committed local dataset (and every version before it) to `url`.

    The order and what each step refuses are in the module docstring; nothing
    is written at `url` before every refusal has had its chance.

    Args:
        local_root: the local dataset folder.
        url: an fsspec URL (or a local path) naming the destination folder.
        on_file: called as (done, total, relative path) after each uploaded and verified file.
        check: called with (root, pinned version) before anything is hashed or uploaded; raises to refuse.

    Raises:
        ArgumentError: `local_root` is a URL. DestinationRefused: the destination (one line, nothing written).
        FileNotFoundError: not a committed dataset. DatasetError: the source is damaged.
        BackendMissing: no fsspec backend for the URL's protocol.
    """
    if storage.is_url(os.fspath(local_root)):
        raise ArgumentError(f"{local_root}: publish reads a LOCAL dataset directory")
    t0 = time.perf_counter()   # the whole publish: checks, validation and hashing included
    root = Path(local_root)
    dest = open_destination(url)
    refuse_overlap(root, dest)
    pinned = pin_dataset(root)
    check_identity(dest, read_state(dest), pinned.version_files, pinned.version)
    if check is not None:
        check(root, pinned.version)
    sums = verify_sources(pinned)
    with ExitStack() as held:
        if dest.local is not None:   # a local folder may be someone's live dataset: its writers' lock
            held.enter_context(WriterLock(dest.local, f"htdata publish {root} {url}"))
            check_identity(dest, read_state(dest), pinned.version_files, pinned.version)
        return _upload(dest, pinned, sums, on_file, t0)


def _upload(dest: Destination, pinned: PinnedDataset, sums: dict[str, str],
            on_file: Callable[[int, int, str], None] | None, t0: float) -> PublishResult:
    """Steps 5 and 6 of the module docstring, after every refusal."""
    fs = dest.fs
    state = read_state(dest)
    new_versions = [n for n in sorted(pinned.version_files) if n and n not in state.versions]
    todo = survey(dest, pinned, sums)
    pointer_changes = state.pointer != pinned.pointer
    marker = marker_bytes(pinned.version_files)
    if marker_versions_differ(state, pinned):   # first: a resumed publish knows its own earlier attempt by it
        upload_whole(fs, marker, dest.path(MARKER))
    progress = _Progress(on_file, len(todo) + len(new_versions) + int(pointer_changes))
    for rel in todo:
        local = pinned.root / rel
        written = upload_file(fs, local, dest.path(rel))
        if written != sums[rel]:
            raise DatasetError(f"{local}: changed while being published (sha256 {written[:12]}, verified "
                               f"{sums[rel][:12]}); {dest.url} still holds what it held before")
        back = remote_sha256(fs, dest.path(rel))
        if back != written:
            raise IOError(f"{dest.url}/{rel}: uploaded sha256 {written[:12]} but read back {back[:12]}")
        progress.done(rel, local.stat().st_size)
    crash_point("publish_files_uploaded")
    # Version files after the files they list: on a local disk a version file present IS a committed version.
    for n in new_versions:
        upload_whole(fs, pinned.version_files[n], dest.path(version_manifest_file(n)))
        progress.done(version_manifest_file(n), len(pinned.version_files[n]))
    if pointer_changes:
        now = read_state(dest).pointer_version
        if now is not None and now > pinned.version:   # another publish got there first: never roll it back
            raise DestinationRefused(f"{dest.url}: moved on to version {now} while this publish of version "
                                     f"{pinned.version} ran; its dataset.json was left as it is")
        # The manifest goes last: only now does the URL name the new version.
        upload_whole(fs, pinned.pointer, dest.path(MANIFEST_FILE))
        progress.done(MANIFEST_FILE, len(pinned.pointer))
    kept = len(pinned.files) - len(todo) + len([n for n in pinned.version_files if n]) - len(new_versions)
    return PublishResult(url=dest.url, version=pinned.version, files=progress.files, bytes=progress.bytes,
                         kept=kept, seconds=time.perf_counter() - t0)


def marker_versions_differ(state, pinned: PinnedDataset) -> bool:
    """Whether the destination's publish marker lacks (or misstates) a version being published."""
    return state.marker != {n: hashlib.sha256(data).hexdigest() for n, data in pinned.version_files.items()}


class _Progress:
    """Counts what went up and tells the caller after each file."""

    def __init__(self, on_file: Callable[[int, int, str], None] | None, total: int):
        self.on_file, self.total, self.files, self.bytes = on_file, total, 0, 0

    def done(self, rel: str, size: int) -> None:
        self.files, self.bytes = self.files + 1, self.bytes + size
        if self.on_file is not None:
            self.on_file(self.files, self.total, rel)


# -- index cache for remote readers ----------------------------------------

def cached_index_path(root_url: str, manifest: dict) -> Path:
    """Local copy of a remote dataset's index.npy, downloaded once.

    Kept as CACHE/index/<index_sha256>/index.npy (a dataset folder of its own,
    so `indexfile.load_index_file` opens it). The download is checked against the
    manifest's sha256 before it replaces anything; concurrent readers each
    write their own temp file and the rename is atomic.
    """
    sha = manifest.get("index_sha256")
    if not isinstance(sha, str) or len(sha) != 64:
        raise DatasetError(f"{root_url}: manifest has no index_sha256; cannot cache the index")
    target = cache_dir() / "index" / sha / INDEX_FILE
    if target.is_file():
        return target
    src = storage.join(root_url, manifest.get("index_file", INDEX_FILE))
    with atomic_open(target) as out, storage.open_binary(src) as f:
        h = hashlib.sha256()
        for block in iter(lambda: f.read(CHUNK), b""):
            h.update(block)
            out.write(block)
        if h.hexdigest() != sha:
            raise DatasetError(f"{src}: downloaded index sha256 {h.hexdigest()[:12]} != manifest {sha[:12]}")
    return target


def load_cached_index(root_url: str, manifest: dict) -> np.ndarray:
    """The remote dataset's index, memory-mapped from the local cache."""
    return load_index_file(str(cached_index_path(root_url, manifest)))
