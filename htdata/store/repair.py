"""`htdata repair`: bring the pointer (dataset.json) back in line with the version files, dry-runnable.

The version files are the truth and dataset.json is a cache of the newest
one (htdata/store/versions.py). Readers and writers already read the newest
version file, so a missing, truncated, stale or hand-rolled-back
dataset.json loses nothing; repair rewrites it so tools that read the
pointer directly see the current version again. The one case readers refuse
is the reverse: dataset.json names a version whose file is gone or garbled
(deleted by hand). Repair restores that file from dataset.json, a byte copy
of it, once the version's record files (its segments, or format 3's episode
and index files) match the sha256 the pointer records. Anything else it
cannot decide is reported, not guessed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from htdata.fileio import write_bytes_atomic
from htdata.format.table import MANIFEST_FILE
from htdata.store.confine import PathOutsideDataset, inside
from htdata.store.lock import WriterLock
from htdata.store.versions import _version_files, version_manifest_file


@dataclass
class RepairPlan:
    actions: list[tuple[str, str, bytes]] = field(default_factory=list)   # (description, relative path, bytes)
    problems: list[str] = field(default_factory=list)                    # what repair cannot fix

    def lines(self, dry_run: bool) -> list[str]:
        would = "would " if dry_run else ""
        out = [f"{would}{what}" for what, _, _ in self.actions] + [f"cannot repair: {p}" for p in self.problems]
        return out or ["nothing to repair: dataset.json is a copy of the newest version file"]


def _parse(data: bytes) -> dict | None:
    try:
        doc = json.loads(data)
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


def _files_match(root: Path, manifest: dict) -> bool:
    """The version's record files are there with the sha256 the manifest records: its segments (format 4),
    or its episode and index files (format 3)."""
    segments = manifest.get("segments")
    if segments is not None and not (isinstance(segments, list) and all(isinstance(e, dict) for e in segments)):
        return False      # a damaged pointer: nothing to match
    listed = [(e.get(k), e.get(f"{k}_sha256")) for e in segments or [] for k in ("records", "index")]
    if segments is None:
        listed = [(manifest.get(f"{stem}_file"), manifest.get(f"{stem}_sha256")) for stem in ("episodes", "index")]
    for rel, sha in listed:
        try:
            path = Path(inside(root, rel, "record file"))    # a pointer never makes repair read outside the dataset
        except PathOutsideDataset:
            return False
        if not path.is_file() or hashlib.sha256(path.read_bytes()).hexdigest() != sha:
            return False
    return True


def plan_repair(root: Path) -> RepairPlan:
    plan = RepairPlan()
    pointer_path = root / MANIFEST_FILE
    pointer_bytes = pointer_path.read_bytes() if pointer_path.is_file() else None
    pointer = _parse(pointer_bytes) if pointer_bytes is not None else None
    versions = _version_files(root)
    named = pointer.get("version") if pointer else None
    if isinstance(named, int) and (named not in versions or _parse((root / version_manifest_file(named)).read_bytes()) is None):
        if versions and named < versions[-1]:
            pass   # an older version's file is damaged but the newest is fine: the pointer moves to the newest
        elif _files_match(root, pointer):
            plan.actions.append((f"restore {version_manifest_file(named)} from {MANIFEST_FILE}",
                                 version_manifest_file(named), pointer_bytes))
            return plan
        else:
            plan.problems.append(f"{version_manifest_file(named)} is missing or damaged and its record files (segments, "
                                 f"or episode and index files) do not match {MANIFEST_FILE}; restore it from a backup")
            return plan
    for n in reversed(versions):   # the newest readable version file becomes the pointer
        data = (root / version_manifest_file(n)).read_bytes()
        if _parse(data) is None:
            plan.problems.append(f"{version_manifest_file(n)} is not valid JSON and {MANIFEST_FILE} holds no copy "
                                 f"of it; restore it from a backup (or move it aside to make version {n - 1} current)")
            return plan
        if data != pointer_bytes:
            was = "missing" if pointer_bytes is None else ("unreadable" if pointer is None else f"naming version {named}")
            plan.actions.append((f"rewrite {MANIFEST_FILE} ({was}) from {version_manifest_file(n)}, the newest version",
                                 MANIFEST_FILE, data))
        return plan
    if pointer_bytes is None:
        plan.problems.append(f"{root}: no version files and no {MANIFEST_FILE}: not an htdata dataset")
    return plan


def repair(root, dry_run: bool, command: str) -> RepairPlan:
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such dataset directory")
    if dry_run:
        return plan_repair(root)
    with WriterLock(root, command):
        plan = plan_repair(root)
        for _, rel, data in plan.actions:
            write_bytes_atomic(root / rel, data)
        return plan
