"""The version `htdata validate` checks, as it reads it: manifest, episode records and index, each read
once and schema-checked, every failure named (`load_dataset`).

A format 3 version's episodes.jsonl and index.npy are checked against the sha256 its manifest records;
a format 4 version's segments each against theirs (htdata/store/segments.py), and the records they
give against the manifest's episodes_sha256 and index_sha256.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.format.table import INDEX_DTYPE, MANIFEST_FILE
from htdata.resources import validate_json
from htdata.store.confine import PathOutsideDataset, inside
from htdata.store.indexfile import IndexDtypeError, parse_index
from htdata.store.manifest import parse_episodes, parse_manifest
from htdata.store.segments import check_segment_rows, load_segment_index, segmented, segmented_records
from htdata.store.versions import manifest_path, version_manifest_file
from htdata.validate.report import Check


@dataclass
class Loaded:
    """A committed dataset as validation reads it (manifest bytes kept: splits record their sha256)."""
    root: Path
    manifest: dict
    manifest_bytes: bytes
    episodes: list[dict]
    index: np.ndarray


def load_dataset(root: Path, check: Check, version: int | None = None) -> Loaded | None:
    """Read and schema-check manifest, episodes and index of the current version (or `version`).

    None when nothing more can be checked.
    """
    manifest = _load_manifest(root, check, version)
    if manifest is None:
        return None
    manifest, manifest_bytes = manifest
    if segmented(manifest):
        return _load_segmented(root, manifest, manifest_bytes, check)
    episodes = _load_episodes(root, manifest, check)
    if episodes is None:
        return None
    index = _load_index(root, manifest, check)
    if index is None:
        return None
    return Loaded(root, manifest, manifest_bytes, episodes, index)


def _load_segmented(root: Path, manifest: dict, manifest_bytes: bytes, check: Check) -> Loaded | None:
    """A format 4 version: its segments read and checked (sha256 of every file), the records re-derived
    and held against the digests the manifest records (episodes_sha256, index_sha256)."""
    try:
        expanded, episodes = segmented_records(root, manifest)
        check_segment_rows(root, manifest)      # every file read, even when the assembled index is cached
        index = load_segment_index(root, manifest)
    except PathOutsideDataset as exc:
        check.fail("path_outside", str(exc), file="segments")
        return None
    except (OSError, ValueError) as exc:     # a missing, changed or unreadable segment: named by the message
        check.fail("segment_damaged", str(exc), file="segments")
        return None
    for line_no, rec in enumerate(episodes, 1):
        try:
            validate_json(rec, "episode", where=f"episode record {line_no} ({rec.get('episode_id')!r})")
        except ValueError as exc:
            check.fail("episode_schema", str(exc), episode=rec.get("episode_id"))
            return None
        check.checked["episode_records"] += 1
    found = hashlib.sha256("".join(json.dumps(ep, sort_keys=True) + "\n"
                                   for ep in episodes).encode()).hexdigest()
    if found != manifest["episodes_sha256"]:
        check.fail("episodes_sha256", "the episode records its segments hold differ from the manifest's "
                   "episodes_sha256", file="segments", expected=manifest["episodes_sha256"], found=found)
    ids = Counter(ep["episode_id"] for ep in episodes)
    for eid, c in ids.items():
        if c > 1:
            check.fail("episode_duplicate", f"episode id {eid!r} appears {c} times", episode=eid)
    return Loaded(root, expanded, manifest_bytes, episodes, index)


def _load_manifest(root: Path, check: Check, version: int | None) -> tuple[dict, bytes] | None:
    try:
        mpath = Path(manifest_path(root, version))
    except FileNotFoundError as exc:      # no such version: names the ones there are
        check.fail("manifest_missing", str(exc), file=str(root))
        return None
    except ValueError as exc:             # dataset.json names a version whose file is gone: names the fix
        check.fail("manifest_missing", str(exc), file=MANIFEST_FILE)
        return None
    rel = str(mpath.relative_to(root)) if mpath.is_relative_to(root) else str(mpath)
    if not mpath.is_file():
        if not root.exists():   # a typo in the path: say that, not that a folder lacks a file
            why = f"{root}: no such folder"
        elif not root.is_dir():
            why = f"{root}: is a file, not a dataset folder"
        else:
            why = f"{mpath}: no {MANIFEST_FILE} (not a committed dataset)"
        check.fail("manifest_missing", why, file=str(mpath))
        return None
    manifest_bytes = mpath.read_bytes()
    try:
        manifest = parse_manifest(manifest_bytes, str(mpath))
    except ValueError as exc:             # also a truncated version file (JSONDecodeError is a ValueError)
        check.fail("manifest_schema", f"{rel}: {exc}", file=rel)
        return None
    if version is None and "version" in manifest:   # the pointer must be a copy of the newest version file
        pointer = root / MANIFEST_FILE
        if not pointer.is_file() or pointer.read_bytes() != manifest_bytes:
            check.fail("manifest_pointer", f"{MANIFEST_FILE} is missing or differs from "
                       f"{version_manifest_file(manifest['version'])}, the newest version (edited by hand, or a "
                       f"write killed before it updated the pointer); `htdata repair {root}` rewrites it",
                       file=MANIFEST_FILE)
    check.checked["manifest"] += 1
    return manifest, manifest_bytes


def _read_listed(root: Path, manifest: dict, stem: str, check: Check) -> tuple[Path, bytes] | None:
    """The file the manifest lists as `{stem}_file`, its sha256 checked against `{stem}_sha256`."""
    try:
        path = Path(inside(root, manifest[f"{stem}_file"], f"{stem}_file"))
    except PathOutsideDataset as exc:   # a symlink out of the dataset: named, never read
        check.fail("path_outside", str(exc), file=manifest[f"{stem}_file"])
        return None
    if not path.is_file():
        check.fail(f"{stem}_missing", f"{path} missing", file=manifest[f"{stem}_file"])
        return None
    data = path.read_bytes()
    found = hashlib.sha256(data).hexdigest()
    if found != manifest[f"{stem}_sha256"]:
        check.fail(f"{stem}_sha256", f"{manifest[f'{stem}_file']}: sha256 differs from the manifest",
                   file=manifest[f"{stem}_file"], expected=manifest[f"{stem}_sha256"], found=found)
    return path, data


def _load_episodes(root: Path, manifest: dict, check: Check) -> list[dict] | None:
    listed = _read_listed(root, manifest, "episodes", check)
    if listed is None:
        return None
    epath, ebytes = listed
    text = ebytes.decode("utf-8", "replace")
    try:
        episodes = parse_episodes(text, epath.name)
    except ValueError as exc:          # names the file and line
        check.fail("episode_schema", str(exc), file=epath.name)
        return None
    # parse_episodes skips blank lines: map each record back to its line for messages
    line_numbers = [no for no, line in enumerate(text.splitlines(), 1) if line.strip()]
    for line_no, rec in zip(line_numbers, episodes):
        try:
            validate_json(rec, "episode", where=f"{epath.name}:{line_no}")
        except ValueError as exc:
            check.fail("episode_schema", str(exc), file=epath.name, line=line_no)
            return None
        check.checked["episode_records"] += 1
    ids = Counter(ep["episode_id"] for ep in episodes)
    for eid, c in ids.items():
        if c > 1:
            check.fail("episode_duplicate", f"episode id {eid!r} appears {c} times", episode=eid)
    return episodes


def _load_index(root: Path, manifest: dict, check: Check) -> np.ndarray | None:
    listed = _read_listed(root, manifest, "index", check)
    if listed is None:
        return None
    ipath, data = listed
    try:
        return parse_index(data, str(ipath))
    except IndexDtypeError as exc:
        check.fail("index_dtype", f"{ipath.name}: wrong dtype", file=ipath.name,
                   expected=str(INDEX_DTYPE), found=str(exc.found))
    except ValueError as exc:
        check.fail("index_unreadable", str(exc), file=ipath.name)
    return None
