"""A dataset's records never reach outside its folder.

A dataset may come from a stranger: every path its manifest names (episodes,
index, layouts, canonical maps, splits, shards) is relative, has no `..`
part, and, on a local disk, resolves (symlinks followed) inside the dataset
root. `parse_manifest` checks the names of every manifest it loads, so open,
validate, publish and gc all refuse such a version with one line naming the
record; `inside` checks where a local file really is before it is read or
uploaded. A symlink that stays inside the root is fine.
"""

from __future__ import annotations

import os
import re

from htdata.errors import HtdataError
from htdata.format.table import SHARDS_DIR
from htdata.store import storage

# the shard names the format writes (format/table.py shard_name): the only files gc may delete in shards/
SHARD_NAME = re.compile(r"^shard-[0-9]{6}-[0-9]{3}\.tar$")


class PathOutsideDataset(HtdataError, ValueError):
    """A path a dataset's records name that is absolute, holds `..`, or resolves outside the dataset root."""


def check_relpath(rel, where: str, field: str) -> str:
    """`rel` when it is a plain relative path below the root; else PathOutsideDataset naming `field`."""
    if not isinstance(rel, str) or not rel:
        raise PathOutsideDataset(f"{where}: {field} must be a relative path, found {rel!r}")
    parts = rel.replace("\\", "/").split("/")
    if rel.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", rel) or "://" in rel:
        raise PathOutsideDataset(f"{where}: {field} {rel!r} is absolute: a dataset's records name files "
                                 f"inside the dataset folder only")
    if ".." in parts or "\x00" in rel:
        raise PathOutsideDataset(f"{where}: {field} {rel!r} climbs out with '..': a dataset's records name "
                                 f"files inside the dataset folder only")
    return rel


def record_paths(manifest: dict) -> list[tuple[str, object]]:
    """(field, path) for every file a manifest names, relative to the dataset root."""
    out: list[tuple[str, object]] = []
    for key in ("episodes_file", "index_file"):
        if key in manifest:
            out.append((key, manifest[key]))
    for lid, entry in (manifest.get("layouts") or {}).items():
        for key in ("file", "coverage"):
            if isinstance(entry, dict) and key in entry:
                out.append((f"layouts.{lid}.{key}", entry[key]))
    canonical = manifest.get("canonical") or {}
    for key in ("file", "regions", "parts"):
        if isinstance(canonical, dict) and key in canonical:
            out.append((f"canonical.{key}", canonical[key]))
    for name, entry in (manifest.get("splits") or {}).items():
        if isinstance(entry, dict) and "file" in entry:
            out.append((f"splits.{name}.file", entry["file"]))
    for i, entry in enumerate(manifest.get("segments") or []):
        for key in ("records", "index"):
            if isinstance(entry, dict) and key in entry:
                out.append((f"segments[{i}].{key}", entry[key]))
    for i, shard in enumerate(manifest.get("shards") or []):
        name = shard.get("name") if isinstance(shard, dict) else None
        if not isinstance(name, str) or "/" in name or "\\" in name or name in ("", ".", ".."):
            raise PathOutsideDataset(f"shards[{i}].name {name!r} is not a plain file name in {SHARDS_DIR}/")
        out.append((f"shards[{i}].name", f"{SHARDS_DIR}/{name}"))
    return out


def check_manifest_paths(manifest: dict, where: str) -> None:
    """Refuse a manifest naming any file outside the dataset folder (one line naming the record)."""
    try:
        for field, rel in record_paths(manifest):
            check_relpath(rel, where, field)
    except PathOutsideDataset as exc:
        text = str(exc)
        raise PathOutsideDataset(text if text.startswith(str(where)) else f"{where}: {text}") from None


def inside(root: str | os.PathLike, rel: str, field: str = "path") -> str:
    """root/rel, after checking rel (and, on a local disk, that it resolves inside root through any symlink)."""
    check_relpath(rel, os.fspath(root), field)
    path = storage.join(root, rel)
    local = storage.local_path(path)
    if local is not None:
        base = os.path.realpath(storage.local_path(root))
        real = os.path.realpath(local)
        if real != base and not real.startswith(base.rstrip(os.sep) + os.sep):
            raise PathOutsideDataset(f"{path}: resolves to {real}, outside the dataset folder {base} "
                                     f"(a symlink?); refused")
    return path
