"""Where `htdata publish` may write: never into its own dataset, never over another dataset.

A destination is refused, before anything is written, when:

- its URL names no folder (`file://`, `memory://`: an empty path would be the
  current folder, or the filesystem's root);
- on a local disk, it is the source dataset, lies inside it, or holds it,
  with symlinks resolved (`DS`, a symlink to `DS`, `file://.` inside `DS`),
  or it lies inside another htdata dataset;
- it is a file, or a folder holding files but no htdata dataset or publish
  marker (someone's data);
- it holds a dataset of another identity (below), or a newer copy of this one.

Identity. An htdata manifest carries no dataset id, but its version files are
one: `versions/vN.json` is written once and never rewritten, and names its
parent, its creation time and author, and the sha256 of every shard and
record of that version. Two folders hold the same dataset exactly when they
have at least one version number in common and, for every number both have,
byte-identical version files (a `dataset.json` counts as the version it
names; an unversioned dataset's `dataset.json` as version 0; the marker
`.htdata-publish.json`, which every publish writes before anything else,
records the sha256 of each version file it publishes, so a first publish
interrupted before its version files went up is known too). A copy made by
an earlier publish of this dataset passes; any other dataset fails at its
first version (its `created` time and shards differ), and a copy whose
versions were all collected by `htdata gc` here shares none and is refused
as unprovable. A destination whose `dataset.json` names a version newer than
the one published is ahead of the source: publishing would roll it back.
"""

from __future__ import annotations

import hashlib
import json
import os
import posixpath
import re
from dataclasses import dataclass
from pathlib import Path

from htdata.errors import ArgumentError
from htdata.format.table import MANIFEST_FILE
from htdata.store import storage
from htdata.store.lock import LOCK_FILE
from htdata.store.versions import VERSIONS_DIR

_VERSION_FILE = re.compile(r"^v(\d{6,})\.json$")
TEMP_SUFFIX = ".publish-tmp"   # what `htdata publish` names a file while it uploads it (remote.py)
MARKER = ".htdata-publish.json"  # written first by every publish: the version sha256s it is publishing


class DestinationRefused(ArgumentError):
    """The URL given to `htdata publish` is not a place it may write; nothing was written there."""


@dataclass
class Destination:
    """An fsspec filesystem and the folder inside it that a publish writes."""
    url: str
    fs: object
    base: str              # path inside `fs`, no trailing "/"
    local: Path | None     # the folder on this machine's disk, when the filesystem is local

    def path(self, rel: str) -> str:
        return f"{self.base}/{rel}"


def open_destination(url: str) -> Destination:
    """The destination a URL names; DestinationRefused when it names no folder (BackendMissing: no backend)."""
    text = os.fspath(url).strip()
    after = text.split("://", 1)[1] if "://" in text else text
    if not after.strip("/"):
        raise DestinationRefused(f"{url!r}: names no folder to publish into (an empty path would be the "
                                 f"current folder or the filesystem's root); give one, e.g. file:///mnt/share/ds; "
                                 f"nothing was written")
    fs, base = storage.url_to_fs(text)
    base = base.rstrip("/") or "/"
    protocols = fs.protocol if isinstance(fs.protocol, (tuple, list)) else (fs.protocol,)
    local = Path(os.path.abspath(base)) if {"file", "local"} & set(protocols) else None
    return Destination(url=text, fs=fs, base=base, local=local)


def _is_dataset(folder: Path) -> bool:
    return (folder / MANIFEST_FILE).exists() or (folder / VERSIONS_DIR).is_dir()


def refuse_overlap(source: Path, dest: Destination) -> None:
    """DestinationRefused when a local destination is, holds or lies inside `source` (symlinks resolved),
    or lies inside another dataset. Remote destinations cannot overlap a local folder."""
    if dest.local is None:
        return
    real_src, real_dst = Path(os.path.realpath(source)), Path(os.path.realpath(dest.local))
    if real_dst == real_src or real_src in real_dst.parents or _same_folder_above(real_dst, real_src):
        where = "the dataset being published itself" if real_dst == real_src else \
            f"inside the dataset being published ({real_src})"
        raise DestinationRefused(f"{dest.url}: resolves to {real_dst}, {where}; publish into a folder outside "
                                 f"it; nothing was written")
    if real_dst in real_src.parents:
        raise DestinationRefused(f"{dest.url}: resolves to {real_dst}, which holds the dataset being published "
                                 f"({real_src}); publish into a folder outside it; nothing was written")
    other = next((p for p in real_dst.parents if _is_dataset(p)), None)
    if other is not None:
        raise DestinationRefused(f"{dest.url}: lies inside the htdata dataset {other}; publish into a folder "
                                 f"of its own; nothing was written")


def _same_folder_above(path: Path, folder: Path) -> bool:
    """True when `path` or an existing folder above it is `folder` itself (a bind mount or a hard-linked
    name realpath does not see through)."""
    for p in (path, *path.parents):
        if p.exists():
            try:
                if os.path.samefile(p, folder):
                    return True
            except OSError:
                return False
    return False


@dataclass
class DestinationState:
    """What a destination holds: its version files (number -> bytes), its dataset.json and the version it
    names, and the version sha256s a publish's marker records (number -> sha256)."""
    versions: dict[int, bytes]
    pointer: bytes | None
    pointer_version: int | None     # 0: an unversioned dataset's dataset.json; None: no dataset.json
    marker: dict[int, str]
    exists: bool


def read_state(dest: Destination) -> DestinationState:
    """The version files, dataset.json and publish marker at the destination (small files: read whole)."""
    fs = dest.fs
    if not fs.exists(dest.base):
        return DestinationState({}, None, None, {}, exists=False)
    if not fs.isdir(dest.base):
        raise DestinationRefused(f"{dest.url}: is a file, not a folder; publish writes a folder; nothing was written")
    versions: dict[int, bytes] = {}
    vdir = dest.path(VERSIONS_DIR)
    if fs.isdir(vdir):
        for entry in fs.ls(vdir, detail=False):
            m = _VERSION_FILE.match(posixpath.basename(entry.rstrip("/")))
            if m:
                versions[int(m.group(1))] = fs.cat_file(entry)
    pointer = fs.cat_file(dest.path(MANIFEST_FILE)) if fs.isfile(dest.path(MANIFEST_FILE)) else None
    marker = fs.cat_file(dest.path(MARKER)) if fs.isfile(dest.path(MARKER)) else None
    return DestinationState(versions, pointer, _named_version(dest, pointer), _marker_versions(dest, marker),
                            exists=True)


def _named_version(dest: Destination, pointer: bytes | None) -> int | None:
    if pointer is None:
        return None
    try:
        doc = json.loads(pointer)
    except ValueError:
        doc = None
    if not isinstance(doc, dict) or doc.get("format") != "htdata":
        raise DestinationRefused(f"{dest.url}/{MANIFEST_FILE}: is not an htdata manifest; publish never "
                                 f"replaces what it did not write: choose another URL; nothing was written")
    version = doc.get("version", 0)
    return version if isinstance(version, int) and version >= 0 else 0


def marker_bytes(version_files: dict[int, bytes]) -> bytes:
    """The publish marker for a source's version files: what lets a resumed publish know its own folder."""
    doc = {"written_by": "htdata publish", "version_sha256": {str(n): hashlib.sha256(data).hexdigest()
                                                            for n, data in sorted(version_files.items())}}
    return (json.dumps(doc, indent=1) + "\n").encode()


def _marker_versions(dest: Destination, data: bytes | None) -> dict[int, str]:
    if data is None:
        return {}
    try:
        doc = json.loads(data)
        return {int(n): str(sha) for n, sha in doc["version_sha256"].items()}
    except (ValueError, KeyError, TypeError, AttributeError):
        raise DestinationRefused(f"{dest.url}/{MARKER}: is not a marker htdata publish wrote; remove it or "
                                 f"choose another URL; nothing was written") from None


def check_identity(dest: Destination, state: DestinationState, ours: dict[int, bytes], pinned: int) -> None:
    """Refuse a destination holding another dataset, a newer copy of this one, or someone's files.

    Args:
        dest: the destination.
        state: what it holds (`read_state`).
        ours: the source's version files up to the pinned version (0 -> an unversioned dataset.json).
        pinned: the version being published (0: unversioned).

    Raises:
        DestinationRefused: with one line saying which, and that nothing was written.
    """
    # every record of the destination that vouches for a version: version files, dataset.json, the marker
    evidence = [(n, hashlib.sha256(data).hexdigest()) for n, data in sorted(state.versions.items())]
    if state.pointer is not None:
        evidence.append((state.pointer_version, hashlib.sha256(state.pointer).hexdigest()))
    evidence += sorted(state.marker.items())
    if not evidence:
        _refuse_foreign_files(dest, state)
        return
    mine = {n: hashlib.sha256(data).hexdigest() for n, data in ours.items()}
    common = [(n, sha) for n, sha in evidence if n in mine]
    differing = [n for n, sha in common if sha != mine[n]]
    if differing or not common:
        theirs = {n for n, _ in evidence}
        what = (f"its version {differing[0]} differs from this dataset's" if differing else
                f"it shares no version with this dataset (it has {_numbers(theirs)}, this one {_numbers(set(ours))})")
        raise DestinationRefused(f"{dest.url}: holds another htdata dataset ({what}); publish never writes over "
                                 f"another dataset: choose another URL; nothing was written")
    if state.pointer_version is not None and state.pointer_version > pinned:
        raise DestinationRefused(f"{dest.url}: already holds version {state.pointer_version} of this dataset, newer "
                                 f"than its version {pinned} being published; publishing would roll it back; "
                                 f"nothing was written")


def _numbers(versions: set[int]) -> str:
    keys = sorted(versions)
    names = ["unversioned" if k == 0 else f"v{k}" for k in keys]
    return names[0] if len(names) == 1 else f"{names[0]}..{names[-1]}"


def _refuse_foreign_files(dest: Destination, state: DestinationState) -> None:
    """A destination without a dataset must be new or empty (a publish's own temp files aside)."""
    if not state.exists:
        return
    own = {dest.path(LOCK_FILE)}   # the writer lock a publish holds on a local folder
    files = [p for p in dest.fs.find(dest.base) if not p.endswith(TEMP_SUFFIX) and p not in own]
    if files:
        first = posixpath.relpath(sorted(files)[0], dest.base)
        raise DestinationRefused(f"{dest.url}: holds {len(files)} file(s) ({first}, ...) but no htdata dataset; "
                                 f"publish writes only into a new or empty folder, or over an earlier publish of "
                                 f"this dataset: choose another URL; nothing was written")
