"""What `htdata publish` uploads: one pinned version, the versions before it, and the files they list.

Pinning follows the reader's protocol (htdata/store/versions.py): the current
version N is the newest `versions/vN.json`, read once; what is published is
those bytes (they become the destination's `dataset.json`), the version files
before N, and the files their manifests list. A committed version never
changes and a writer only adds new names, so an ingest committing N+1 while a
publish runs changes nothing the publish reads; the local `dataset.json` (a
cache such a commit rewrites) is never read. An unversioned dataset (format 1)
publishes its `dataset.json`, read once, and its `splits/` folder.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from htdata.errors import DatasetError
from htdata.format.table import LAYOUTS_DIR, MANIFEST_FILE, SHARDS_DIR, SPLITS_DIR
from htdata.store.confine import inside, record_paths
from htdata.store.manifest import parse_manifest
from htdata.store.segments import segmented, version_shards
from htdata.store.versions import DatasetStateError, current_version, list_versions, version_manifest_file

DEFAULT_PARTS = f"{LAYOUTS_DIR}/parts.png"   # what readers open when a canonical record names no parts map


@dataclass
class PinnedDataset:
    """One consistent snapshot of a local dataset, as published.

    `version_files` maps each version number up to the pinned one to its
    file's bytes (0: an unversioned dataset's dataset.json); `pointer` is the
    pinned version's bytes; `files` the other files to upload, in order, each
    with the sha256 its manifest records (None where none is recorded).
    """
    root: Path
    version: int
    pointer: bytes
    version_files: dict[int, bytes]
    files: list[tuple[str, str | None]]


def pin_dataset(local_root: str | os.PathLike) -> PinnedDataset:
    """Pin the current version of the committed dataset at `local_root` and list what publishing it uploads.

    Raises:
        FileNotFoundError: not a committed dataset.
        DatasetError: a manifest that does not parse, names a file outside the folder, or lists a file that
            is missing (one line naming it).
    """
    root = Path(local_root)
    n = current_version(root)
    if n is None:
        path = root / MANIFEST_FILE
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no manifest: not a committed htdata dataset")
        version_files = {0: path.read_bytes()}
    else:
        version_files = {}
        for k in list_versions(root):
            if k <= n:
                try:
                    version_files[k] = (root / version_manifest_file(k)).read_bytes()
                except FileNotFoundError:   # collected by a gc meanwhile: no longer a version
                    continue
        if n not in version_files:
            raise DatasetStateError(f"{root / version_manifest_file(n)}: vanished while being read; "
                                    f"run `htdata log {root}` and publish again")
    manifests = {k: _parse(root, k, data) for k, data in version_files.items()}
    return PinnedDataset(root=root, version=n or 0, pointer=version_files[n or 0], version_files=version_files,
                         files=_files(root, manifests))


def _parse(root: Path, n: int, data: bytes) -> dict:
    where = str(root / (version_manifest_file(n) if n else MANIFEST_FILE))
    try:
        return parse_manifest(data, where)
    except json.JSONDecodeError as exc:
        raise DatasetStateError(f"{where}: not valid JSON ({exc}); `htdata validate {root}` names the damage") \
            from None


def _expected(manifest: dict, field: str) -> str | None:
    """The sha256 a manifest records for the file in record field `field`, None where it records none."""
    if field == "episodes_file":
        return manifest.get("episodes_sha256")
    if field == "index_file":
        return manifest.get("index_sha256")
    head, _, key = field.rpartition(".")
    if head.startswith("layouts.") and key == "file":
        return manifest["layouts"][head.split(".", 1)[1]].get("sha256")
    if field == "canonical.file":
        return manifest["canonical"].get("sha256")
    if head.startswith("splits.") and key == "file":
        return manifest["splits"][head.split(".", 1)[1]].get("sha256")
    if field.startswith("segments["):
        entry = manifest["segments"][int(field[9:field.index("]")])]
        return entry.get(f"{field.rsplit('.', 1)[1]}_sha256")
    if field.startswith("shards["):
        return manifest["shards"][int(field[7:field.index("]")])]["sha256"]
    return None


def _files(root: Path, manifests: dict[int, dict]) -> list[tuple[str, str | None]]:
    """Every file the pinned manifests list: layouts first, then shards, then each version's records."""
    groups: tuple[list, list, list] = ([], [], [])
    for n in sorted(manifests):
        manifest = manifests[n]
        named = record_paths(manifest)
        if segmented(manifest):    # format 4: the shards are listed by its segments, read and checked here
            manifest["shards"] = version_shards(root, manifest)
            named += [(f"shards[{i}].name", f"{SHARDS_DIR}/{s['name']}") for i, s in enumerate(manifest["shards"])]
        if "parts" not in (manifest.get("canonical") or {}) and (root / DEFAULT_PARTS).is_file():
            named.append(("canonical.parts", DEFAULT_PARTS))
        if n == 0 and (root / SPLITS_DIR).is_dir():     # unversioned: splits/NAME.json, listed by no manifest
            named += [("splits", f"{SPLITS_DIR}/{p.name}") for p in sorted((root / SPLITS_DIR).glob("*.json"))]
        for field, rel in named:
            group = 1 if rel.startswith(f"{SHARDS_DIR}/") else 0 if rel.startswith(f"{LAYOUTS_DIR}/") else 2
            groups[group].append((rel, _expected(manifest, field), n))
    files: dict[str, str | None] = {}
    for rel, sha, n in [*groups[0], *groups[1], *groups[2]]:
        if rel in files and sha is not None and files[rel] not in (None, sha):
            raise DatasetError(f"{root / rel}: version {n or 'unversioned'} records sha256 {sha[:12]}, an earlier "
                               f"version {files[rel][:12]}: a file never changes once listed; the records are damaged")
        if files.get(rel) is None:
            files[rel] = sha
    for rel in files:
        inside(root, rel)   # a dataset never makes publish read, or write, outside its folder
        if not (root / rel).is_file():
            raise DatasetError(f"{root / rel}: listed by the dataset but missing; cannot publish "
                               f"(`htdata validate {root}` names every damage)")
    return list(files.items())
