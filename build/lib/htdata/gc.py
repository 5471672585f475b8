"""`htdata gc`: delete old versions and the shards no kept version lists (explicit, dry-runnable).

Keeps the `keep_versions` newest versions and always the current one.
Deletes, in this order, the manifests of the other versions, their files,
then every shard file no kept version lists (including shards an
interrupted write left behind, which no version ever listed). A crash
between the steps leaves only unreferenced files, which the next gc
removes. The current version's shards are never deleted (checked again
right before deleting). Entries of the `htdata stats` cache that no kept
version's episode uses go too.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

from htdata.faults import crash_point
from htdata.format import SHARDS_DIR
from htdata.lock import WriterLock
from htdata.manifest import load_manifest
from htdata.stats import STATS_DIR
from htdata.versions import list_versions, version_dir, version_manifest_file


@dataclass
class GcPlan:
    kept_versions: list[int]
    dropped_versions: list[int] = field(default_factory=list)
    dropped_shards: list[tuple[str, int]] = field(default_factory=list)   # (name, bytes)
    dropped_stats: list[tuple[str, int]] = field(default_factory=list)    # stats cache entries (name, bytes)

    @property
    def bytes_freed(self) -> int:
        return sum(b for _, b in self.dropped_shards) + sum(b for _, b in self.dropped_stats)

    def lines(self, dry_run: bool = False) -> list[str]:
        would = "would " if dry_run else ""
        out = [f"{would}delete version {v}" for v in self.dropped_versions]
        out += [f"{would}delete shard {name} ({size} B)" for name, size in self.dropped_shards]
        if self.dropped_stats:
            out.append(f"{would}delete {len(self.dropped_stats)} stats cache entries no kept version's episode uses")
        out.append(f"{would}keep versions {', '.join(map(str, self.kept_versions)) or '(unversioned)'}; "
                   f"{len(self.dropped_shards)} shards, {self.bytes_freed} bytes {'would be ' if dry_run else ''}freed")
        return out


def plan_gc(root: Path, keep_versions: int) -> GcPlan:
    if keep_versions < 1:
        raise ValueError(f"--keep-versions must be >= 1 (the current version is always kept), got {keep_versions}")
    current = load_manifest(root)
    versions = list_versions(root)
    kept = sorted(set(versions[-keep_versions:]) | ({current["version"]} if "version" in current else set()))
    plan = GcPlan(kept_versions=kept, dropped_versions=[v for v in versions if v not in kept])
    listed = {s["name"] for s in current["shards"]}
    for v in kept:
        listed |= {s["name"] for s in load_manifest(root, version=v)["shards"]}
    for path in sorted((root / SHARDS_DIR).iterdir()) if (root / SHARDS_DIR).is_dir() else []:
        if path.name not in listed and (path.suffix == ".tar" or path.name.endswith(".tmp")):
            plan.dropped_shards.append((path.name, path.stat().st_size))
    plan.dropped_stats = unused_stats_entries(root, kept or [None])
    return plan


def unused_stats_entries(root: Path, versions: list) -> list[tuple[str, int]]:
    """Entries of the `htdata stats` cache whose episode no kept version holds (name, bytes)."""
    from htdata.reader import DatasetReader
    from htdata.stats import episode_key

    cache = root / STATS_DIR
    if not cache.is_dir():
        return []
    used = set()
    for v in versions:
        with DatasetReader(root, version=v) as reader:
            used |= {f"{episode_key(reader, pos)}.json" for pos in range(len(reader.episodes))}
    return [(p.name, p.stat().st_size) for p in sorted(cache.iterdir()) if p.is_file() and p.name not in used]


def collect(root, keep_versions: int, dry_run: bool, command: str) -> GcPlan:
    """Plan (and unless dry_run, carry out) a gc of the dataset at `root`."""
    root = Path(root)
    with WriterLock(root, command):
        plan = plan_gc(root, keep_versions)
        if dry_run:
            return plan
        current = {s["name"] for s in load_manifest(root)["shards"]}
        doomed = {name for name, _ in plan.dropped_shards}
        if current & doomed:    # never: plan_gc keeps the current version's shards
            raise RuntimeError(f"gc would delete shards of the current version: {sorted(current & doomed)[:3]}")
        for v in plan.dropped_versions:
            (root / version_manifest_file(v)).unlink(missing_ok=True)
            shutil.rmtree(root / version_dir(v), ignore_errors=True)
            crash_point("gc_version_deleted")
        for name in sorted(doomed):
            (root / SHARDS_DIR / name).unlink(missing_ok=True)
        for name, _ in plan.dropped_stats:
            (root / STATS_DIR / name).unlink(missing_ok=True)
        return plan
