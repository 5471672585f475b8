"""Remote datasets: publish a committed dataset to an fsspec URL; cache a remote index locally.

`htdata publish DATASET URL` (htdata/commands/publish.py) runs `publish_dataset`.

Publishing uploads layouts/, shards/ and every committed version (its
manifest, episode file, index and splits; unversioned datasets: splits/,
episodes.jsonl and index.npy),
reads every uploaded file back to check its sha256 against the local file
(and against the manifest where the manifest records one), and writes
dataset.json LAST. A previous dataset.json at the URL is deleted first, so
while an upload runs, or after it failed part way, the URL is never a valid
dataset (readers refuse a directory without a manifest).

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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.format.table import EPISODES_FILE, INDEX_FILE, LAYOUTS_DIR, MANIFEST_FILE, SHARDS_DIR, SPLITS_DIR
from htdata.store import storage
from htdata.store.confine import inside
from htdata.store.fsutil import atomic_open, sha256_file, sha256_stream
from htdata.store.manifest import load_index_file, load_manifest
from htdata.store.versions import list_versions, version_manifest_file

CACHE_ENV = "HTDATA_CACHE"
CHUNK = 1 << 20


@dataclass
class PublishResult:
    url: str
    files: int          # files uploaded, dataset.json included
    bytes: int
    seconds: float


def cache_dir() -> Path:
    """Local cache root: $HTDATA_CACHE, else ~/.cache/htdata."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else Path.home() / ".cache" / "htdata"


# -- publish ----------------------------------------------------------------

def publish_plan(local_root: str | os.PathLike) -> tuple[dict, list[tuple[str, str | None]]]:
    """(manifest, [(relative path, sha256 the manifest expects or None)]) in upload order.

    Everything but dataset.json: layouts and splits first, then shards in
    manifest order, then episodes.jsonl and index.npy (which name the shards).
    Resume state (.work/) and reports are not part of a published dataset.
    """
    root = Path(local_root)
    manifest = load_manifest(root)
    versions = list_versions(root)
    # every committed version travels (remote readers can open any of them), current last
    manifests = [load_manifest(root, version=v) for v in versions if v != manifest.get("version")] + [manifest]
    plan: list[tuple[str, str | None]] = []
    for sub in (LAYOUTS_DIR, SPLITS_DIR):
        folder = root / sub
        if folder.is_dir():
            plan += [(f"{sub}/{p.name}", None) for p in sorted(folder.iterdir()) if p.is_file()]
    for m in manifests:
        plan += [(f"{SHARDS_DIR}/{s['name']}", s["sha256"]) for s in m["shards"]]
    for m in manifests:
        plan.append((m.get("episodes_file", EPISODES_FILE), m.get("episodes_sha256")))
        plan.append((m.get("index_file", INDEX_FILE), m.get("index_sha256")))
        plan += [(e["file"], e["sha256"]) for e in m.get("splits", {}).values()]
    plan += [(version_manifest_file(v), None) for v in versions]
    plan = list(dict.fromkeys(plan))   # shards shared by versions once, in first-listed order
    for rel, _ in plan:
        inside(root, rel)   # a dataset never makes publish read, or write, outside its folder
        if not (root / rel).is_file():
            raise FileNotFoundError(f"{root / rel}: listed by the dataset but missing; cannot publish")
    return manifest, plan


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


def publish_dataset(local_root: str | os.PathLike, url: str,
                    on_file: Callable[[int, int, str], None] | None = None) -> PublishResult:
    """Upload a committed local dataset to an fsspec URL, verified, manifest last.

    `on_file(done, total, relative path)` is called after each verified file.
    """
    root = Path(local_root)
    if storage.is_url(os.fspath(local_root)):
        raise ArgumentError(f"{local_root}: publish reads a LOCAL dataset directory")
    manifest_path = root / MANIFEST_FILE
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{manifest_path}: no manifest: not a committed htdata dataset")
    _, plan = publish_plan(root)
    fs, base = storage.url_to_fs(url)
    base = base.rstrip("/")
    t0 = time.perf_counter()
    remote_manifest = f"{base}/{MANIFEST_FILE}"
    if fs.exists(remote_manifest):
        fs.rm(remote_manifest)   # the URL stops being a dataset until the new upload is complete
    total = 0
    for n, (rel, expected) in enumerate(plan, 1):
        local = root / rel
        if expected is not None and sha256_file(local) != expected:
            raise DatasetError(f"{local}: sha256 differs from the manifest: the local dataset is damaged "
                               f"(run `htdata validate`); nothing more uploaded")
        written = upload_file(fs, local, f"{base}/{rel}")
        back = remote_sha256(fs, f"{base}/{rel}")
        if back != written:
            raise IOError(f"{url}/{rel}: uploaded sha256 {written[:12]} but read back {back[:12]}")
        total += local.stat().st_size
        if on_file is not None:
            on_file(n, len(plan) + 1, rel)
    # The manifest goes last: only now does the URL hold a valid dataset.
    written = upload_file(fs, manifest_path, remote_manifest)
    if remote_sha256(fs, remote_manifest) != written:
        raise IOError(f"{url}/{MANIFEST_FILE}: read-back sha256 differs from what was uploaded")
    total += manifest_path.stat().st_size
    if on_file is not None:
        on_file(len(plan) + 1, len(plan) + 1, MANIFEST_FILE)
    return PublishResult(url=url, files=len(plan) + 1, bytes=total, seconds=time.perf_counter() - t0)


# -- index cache for remote readers ----------------------------------------

def cached_index_path(root_url: str, manifest: dict) -> Path:
    """Local copy of a remote dataset's index.npy, downloaded once.

    Kept as CACHE/index/<index_sha256>/index.npy (a dataset folder of its own,
    so `manifest.load_index_file` opens it). The download is checked against the
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
