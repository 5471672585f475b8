"""Dataset versions: immutable snapshots over immutable shards; the newest version file is the current one.

The Iceberg / Delta Lake idea at the size of a folder. Shards are immutable
and content-hashed (sha256 in every manifest). A version is a manifest (the
segments it uses, layouts, codec, counts, change summary, parent) plus its own
split files under `versions/`:

    versions/v000003.json            the version's manifest (written once, never rewritten)
    versions/v000003/splits/NAME.json
    segments/<sha16>.json, .npy      episode records and index rows, shared by the versions that list
                                     them (format 4: htdata/store/segments.py)
    versions/v000003/episodes.jsonl  format 3: the version's own episode records ...
    versions/v000003/index.npy       ... and index
    dataset.json                     a copy of the CURRENT version's manifest: the pointer

A write puts the version's files in place first, then links
`versions/vN.json` into place (fails if it exists: no version is ever
overwritten): that link is the commit. Last it swaps `dataset.json` with one
atomic rename; dataset.json is a CACHE of the newest version file, so a
missing, truncated, stale or hand-edited dataset.json loses nothing: the
current version is the newest vN.json (`current_version`), writers build on
it, and `htdata repair` rewrites the cache. A crash at any point leaves the
previous version (or, after the link, the new one) current and readable; a
half written `versions/vN/` without its `vN.json` belongs to no version and
is cleared by the next write. Writers never delete a version file. Old
versions stay readable (`DatasetReader(root, version=N)`) until `htdata gc`
removes them, an explicit, dry-runnable act with a retention window. Why no library: Iceberg / Delta need a table
engine and a catalog for what is here a few JSON files and a rename; zarr's
`.partial` idea is the same temp + rename each writer here already uses.

Datasets written before versions existed (format_version 1) have no
`versions/`: they read as one unnumbered version.
"""

from __future__ import annotations

import datetime as _dt
import getpass
import hashlib
import json
import os
import re
import shutil
import socket
from pathlib import Path

from htdata.errors import ArgumentError, HtdataError
from htdata.faults import crash_point
from htdata.fileio import write_bytes_atomic, write_bytes_exclusive
from htdata.format.table import MANIFEST_FILE, SPLITS_DIR
from htdata.store import storage
from htdata.store.gcrecord import collected_error

VERSIONS_DIR = "versions"
_VERSION_RE = re.compile(r"^v(\d{6,})\.json$")
# Episode record fields that say WHERE an episode sits, not WHAT it holds: ignored by diffs.
POSITIONAL_FIELDS = ("first_sample", "shards")


def version_name(n: int) -> str:
    if n < 1:
        raise ArgumentError(f"versions are numbered from 1, got {n}")
    return f"v{n:06d}"


def version_manifest_file(n: int) -> str:
    return f"{VERSIONS_DIR}/{version_name(n)}.json"


def version_dir(n: int) -> str:
    return f"{VERSIONS_DIR}/{version_name(n)}"


def split_file(n: int | None, name: str) -> str:
    """Where split NAME of version n lives (unversioned datasets: splits/NAME.json)."""
    return f"{SPLITS_DIR}/{name}.json" if n is None else f"{version_dir(n)}/{SPLITS_DIR}/{name}.json"


class DatasetStateError(HtdataError, ValueError):
    """The version files and the pointer disagree in a way no reader can resolve alone; the message
    names the file and the fix (usually `htdata repair DATASET`)."""


def list_versions(root: str | os.PathLike) -> list[int]:
    """Committed version numbers, ascending.

    Local datasets: every versions/vN.json. A version file is linked into
    place complete, after its files (write_version), so its presence IS the
    commit; dataset.json is a cache of the newest one. Remote (published)
    datasets: those up to the version dataset.json names, since `htdata
    publish` uploads dataset.json last.
    """
    if storage.local_path(root) is not None:
        return _version_files(root)
    pointer = storage.join(root, MANIFEST_FILE)
    if not storage.exists(pointer):
        return []
    current = json.loads(storage.read_text(pointer)).get("version") or 0
    return [n for n in _version_files(root) if n <= current]


def _version_files(root: str | os.PathLike) -> list[int]:
    """Numbers of every versions/vN.json present, committed or not."""
    path = storage.join(root, VERSIONS_DIR)
    local = storage.local_path(path)
    if local is not None:
        if not Path(local).is_dir():
            return []
        names = os.listdir(local)
    else:
        names = [p.rstrip("/").rsplit("/", 1)[-1] for p in storage.listdir(path)] if storage.exists(path) else []
    return sorted(int(m.group(1)) for m in map(_VERSION_RE.match, names) if m)


def pointer_version(root: str | os.PathLike) -> tuple[int | None, str | None]:
    """(version dataset.json names, None) or (None, why it names none: missing / unreadable)."""
    path = storage.join(root, MANIFEST_FILE)
    if not storage.exists(path):
        return None, "missing"
    try:
        doc = json.loads(storage.read_text(path))
        version = doc.get("version") if isinstance(doc, dict) else None
    except (OSError, ValueError) as exc:
        return None, f"unreadable ({exc})"
    return (int(version), None) if isinstance(version, int) else (None, "names no version")


def current_version(root: str | os.PathLike) -> int | None:
    """The current version: the newest version file (local), None for an unversioned or empty folder.

    Refuses (DatasetStateError, naming the file and `htdata repair`) when
    dataset.json names a version whose file is gone: reading the next older
    one instead would silently roll the dataset back.
    """
    have = list_versions(root)
    if storage.local_path(root) is None:
        return have[-1] if have else None
    named, _ = pointer_version(root)
    if named is not None and named not in have and (not have or named > have[-1]):
        raise DatasetStateError(
            f"{storage.join(root, version_manifest_file(named))}: missing, but {MANIFEST_FILE} names version "
            f"{named} as current; run `htdata repair {root}` to restore it from {MANIFEST_FILE}")
    return have[-1] if have else None


def manifest_path(root: str | os.PathLike, version: int | None) -> str:
    """The manifest to open: the newest versions/vN.json for the current version (dataset.json when the
    dataset has no versions, or is remote), versions/vN.json for version N."""
    if version is None:
        if storage.local_path(root) is None:
            return storage.join(root, MANIFEST_FILE)
        n = current_version(root)
        return storage.join(root, MANIFEST_FILE if n is None else version_manifest_file(n))
    path = storage.join(root, version_manifest_file(int(version)))
    have = list_versions(root)
    if int(version) not in have:
        gone = collected_error(root, int(version))
        if gone is not None:
            raise gone
        raise FileNotFoundError(f"{root}: no version {version} (versions: "
                                f"{', '.join(map(str, have)) if have else 'none: dataset has no version history'})")
    return path


def now_utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def change_record(command: str, summary: dict, time: str | None = None) -> dict:
    """The "change" entry of a version: who made it, when, with what command, what changed."""
    try:
        author = getpass.getuser()
    except Exception:   # no user name in some containers: record the uid instead
        author = f"uid {os.getuid()}"
    return {"time": time or now_utc(), "author": author, "host": socket.gethostname(), "command": command,
            "summary": summary}


def content_view(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in POSITIONAL_FIELDS}


def diff_episodes(old: list[dict], new: list[dict]) -> dict:
    """{added, removed, changed: [episode ids]} and frame counts between two episode lists.

    "changed" = same id, different record (positions ignored): re-ingested
    from changed inputs, trimmed, renormalised or relabelled. Frames added /
    removed count whole episodes plus what changed episodes gained or lost.
    """
    a = {e["episode_id"]: e for e in old}
    b = {e["episode_id"]: e for e in new}
    added = sorted(set(b) - set(a))
    removed = sorted(set(a) - set(b))
    changed = sorted(e for e in set(a) & set(b) if content_view(a[e]) != content_view(b[e]))
    delta = [int(b[e]["num_frames"]) - int(a[e]["num_frames"]) for e in changed]
    return {"added": added, "removed": removed, "changed": changed,
            "frames_added": sum(int(b[e]["num_frames"]) for e in added) + sum(d for d in delta if d > 0),
            "frames_removed": sum(int(a[e]["num_frames"]) for e in removed) - sum(d for d in delta if d < 0),
            "frames_before": sum(int(e["num_frames"]) for e in old),
            "frames_after": sum(int(e["num_frames"]) for e in new)}


def summarise(diff: dict) -> dict:
    """The counts of a diff (what a version manifest keeps; ids stay in the episode files)."""
    return {"episodes_added": len(diff["added"]), "episodes_removed": len(diff["removed"]),
            "episodes_changed": len(diff["changed"]), "frames_added": diff["frames_added"],
            "frames_removed": diff["frames_removed"], "frames": diff["frames_after"]}


def _link_exclusive(path: Path, data: bytes) -> None:
    """Write `data` to `path`, which must not exist (fileio.write_bytes_exclusive: never overwrites)."""
    try:
        write_bytes_exclusive(path, data)
    except FileExistsError:
        raise FileExistsError(f"{path}: version already exists; versions are never rewritten") from None


def clear_orphans(root: Path, current: int | None) -> None:
    """Remove `versions/vN/` folders numbered after the current version that have no vN.json.

    Such a folder is a write killed before it linked its version file: no
    version lists it, nothing ever read it. Version files are never removed
    here (a present vN.json is a committed version). The caller holds the
    writer lock.
    """
    n = (current or 0) + 1
    committed = set(_version_files(root))
    vdir = root / VERSIONS_DIR
    for d in (vdir.iterdir() if vdir.is_dir() else []):
        if d.is_dir() and re.fullmatch(r"v\d{6,}", d.name) and int(d.name[1:]) >= n \
                and int(d.name[1:]) not in committed:
            shutil.rmtree(d)


def write_version(root: str | os.PathLike, manifest: dict, splits: dict[str, bytes] | None = None) -> dict:
    """Commit `manifest` as version parent + 1; returns it with its version and split files filled in.

    The caller fills parent, change, counts, segments (written before: htdata/store/segments.py)...;
    this writes versions/vN/splits/*, then versions/vN.json, then swaps dataset.json. The caller
    holds the writer lock.
    """
    root = Path(root)
    current = current_version(root)
    if current != manifest.get("parent"):
        # a write must build on the current version: anything else would drop what came after its parent
        raise RuntimeError(f"{root}: the current version is {current}, this write was built on "
                           f"{manifest.get('parent')}; nothing was written (run the command again)")
    clear_orphans(root, manifest.get("parent"))
    n = (manifest.get("parent") or 0) + 1
    files_dir = root / version_dir(n)
    files_dir.mkdir(parents=True)
    split_entries = {}
    for name, data in sorted((splits or {}).items()):
        (files_dir / SPLITS_DIR).mkdir(exist_ok=True)
        write_bytes_atomic(root / split_file(n, name), data)
        split_entries[name] = {"file": split_file(n, name), "sha256": _sha256(data)}
    manifest = dict(manifest)
    manifest.update({"version": n, "splits": split_entries})
    data = (json.dumps(manifest, indent=2) + "\n").encode()
    crash_point("version_files_written")
    _link_exclusive(root / version_manifest_file(n), data)
    crash_point("version_manifest_written")
    write_bytes_atomic(root / MANIFEST_FILE, data)
    return manifest


def restore_pointer(root: str | os.PathLike, n: int) -> bool:
    """Rewrite dataset.json from versions/vN.json (N the newest version) when it is missing or differs;
    True when it was rewritten. A write that changes nothing still leaves the pointer right."""
    root = Path(root)
    if not _version_files(root) or _version_files(root)[-1] != n:
        return False
    data = (root / version_manifest_file(n)).read_bytes()
    pointer = root / MANIFEST_FILE
    if pointer.is_file() and pointer.read_bytes() == data:
        return False
    write_bytes_atomic(pointer, data)
    return True


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


