"""`htdata gc`: delete old versions and the shards and segments no kept version lists (explicit, dry-runnable).

Retention rule (Delta Lake VACUUM / Iceberg remove-orphan-files): a version
that is not among the `--keep-versions` newest is deleted only once it has
been superseded for longer than `--retention` (default 7 days): a reader
(a training job) that opened it while it was current keeps working for that
long. "Superseded" is the time the next version's file was written. A shard
is deleted only when no kept version lists it and it either belonged to a
deleted version or has been on disk, unlisted, longer than the window (an
interrupted write's leftovers). A window shorter than 1 hour needs
`--force`: readers that still hold a collected version then fail, with
`VersionCollected` naming the version and this gc (not a bare missing
file). `--dry-run` lists what would go and what the window keeps.

Before deleting any file of version N, gc writes the tombstone
`versions/vN.collected.json` (when, command, retention). Order per version:
tombstone, vN.json (the version disappears from `htdata log`), then its
folder; a crash in between leaves a `versions/vN/` without vN.json, which
the next gc removes. The current version and its shards are never deleted
(checked again right before deleting). A segment file (format 4: the
episode records and index rows versions share, htdata/store/segments.py) goes
by the shard rule: no kept version lists it, and a dropped version did or it
is older than the window. Entries of the `htdata stats` cache that no kept
version's episode uses go too.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from htdata.errors import ArgumentError, HtdataError
from htdata.faults import crash_point
from htdata.fileio import write_bytes_atomic
from htdata.format.table import SEGMENTS_DIR, SHARDS_DIR, STATS_DIR
from htdata.inspect.stats import episode_key
from htdata.read.reader import DatasetReader
from htdata.store.confine import record_paths
from htdata.store.gcrecord import tombstone_file
from htdata.store.lock import WriterLock
from htdata.store.manifest import load_manifest
from htdata.store.segments import version_shards
from htdata.store.versions import VERSIONS_DIR, current_version, list_versions, version_dir, version_manifest_file

DEFAULT_RETENTION_S = 7 * 86400     # Delta Lake's default; Iceberg uses 3 days
FORCE_BELOW_S = 3600                # a shorter window may break running readers: needs --force
# what gc may delete in shards/: the format's shard names (format/shardio.py shard_name) and their temp files
COLLECTABLE = re.compile(r"\.?shard-[0-9]{6}-[0-9]{3}\.tar(\.tmp)?")
# ... and in segments/: the names htdata/store/segments.py gives (and the temp files of a write cut short)
SEGMENT_FILE = re.compile(r"[0-9a-f]{16}\.(json|npy)|\.[0-9a-f]{16}\.(json|npy)\..*\.tmp")
_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400}


class RetentionTooShort(HtdataError, ValueError):
    """A retention window shorter than FORCE_BELOW_S without force."""


def parse_duration(text: str) -> float:
    """'7d', '36h', '30m', '90s', '0' -> seconds."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smhd]?)\s*", str(text))
    if not m:
        raise ArgumentError(f"--retention {text!r}: expected a duration such as 7d, 36h, 30m, 90s or 0")
    return float(m.group(1)) * _UNITS[m.group(2) or "s"]


def format_duration(seconds: float) -> str:
    for unit in ("d", "h", "m"):
        if seconds >= _UNITS[unit] and seconds % _UNITS[unit] == 0:
            return f"{int(seconds // _UNITS[unit])}{unit}"
    return f"{seconds:g}s"


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).isoformat(timespec="seconds")


@dataclass
class GcPlan:
    kept_versions: list[int]
    dropped_versions: list[int] = field(default_factory=list)
    dropped_shards: list[tuple[str, int]] = field(default_factory=list)   # (name, bytes)
    dropped_stats: list[tuple[str, int]] = field(default_factory=list)    # stats cache entries (name, bytes)
    dropped_segments: list[tuple[str, int]] = field(default_factory=list)  # segment files no kept version lists
    window_kept: list[tuple[int, float]] = field(default_factory=list)    # (version, collectable after: epoch s)
    window_kept_shards: int = 0        # unlisted shards younger than the window
    leftover_dirs: list[str] = field(default_factory=list)               # versions/vN/ without vN.json
    symlinked_shards: bool = False     # shards/ is a symlink: gc deletes nothing through it
    retention_s: float = DEFAULT_RETENTION_S

    @property
    def bytes_freed(self) -> int:
        return sum(b for _, b in self.dropped_shards + self.dropped_stats + self.dropped_segments)

    def lines(self, dry_run: bool = False) -> list[str]:
        would = "would " if dry_run else ""
        window = format_duration(self.retention_s)
        out = [f"{would}delete version {v}" for v in self.dropped_versions]
        out += [f"{would}delete {d}/ (left by an interrupted gc or write: no version file names it)"
                for d in self.leftover_dirs]
        out += [f"{would}delete shard {name} ({size} B)" for name, size in self.dropped_shards]
        if self.dropped_segments:
            out.append(f"{would}delete {len(self.dropped_segments)} segment files no kept version lists")
        if self.dropped_stats:
            out.append(f"{would}delete {len(self.dropped_stats)} stats cache entries no kept version's episode uses")
        out += [f"keep version {v}: superseded less than {window} ago (retention window), collectable after "
                f"{_iso(t)}" for v, t in self.window_kept]
        if self.window_kept_shards:
            out.append(f"keep {self.window_kept_shards} unlisted shards written less than {window} ago "
                       f"(retention window)")
        if self.symlinked_shards:
            out.append(f"{SHARDS_DIR}/ is a symlink: gc deletes no shard through it (collect them where it points)")
        out.append(f"{would}keep versions {', '.join(map(str, self.kept_versions)) or '(unversioned)'}; "
                   f"{len(self.dropped_shards)} shards, {self.bytes_freed} bytes {'would be ' if dry_run else ''}freed")
        return out


def plan_gc(root: Path, keep_versions: int, retention_s: float = DEFAULT_RETENTION_S,
            now: float | None = None) -> GcPlan:
    if keep_versions < 1:
        raise ArgumentError(f"--keep-versions must be >= 1 (the current version is always kept), got {keep_versions}")
    now = time.time() if now is None else now
    current = load_manifest(root)
    versions = list_versions(root)
    by_count = set(versions[-keep_versions:]) | ({current["version"]} if "version" in current else set())
    plan = GcPlan(kept_versions=[], retention_s=retention_s)
    for i, v in enumerate(versions):
        if v in by_count:
            continue
        superseded = (root / version_manifest_file(versions[i + 1])).stat().st_mtime
        if now - superseded < retention_s:
            plan.window_kept.append((v, superseded + retention_s))
        else:
            plan.dropped_versions.append(v)
    plan.kept_versions = [v for v in versions if v not in plan.dropped_versions]
    listed = {s["name"] for s in version_shards(root, current)}
    for v in plan.kept_versions:
        listed |= {s["name"] for s in version_shards(root, load_manifest(root, version=v))}
    of_dropped = {s["name"] for v in plan.dropped_versions for s in version_shards(root, load_manifest(root, version=v))}
    shard_dir = root / SHARDS_DIR
    plan.symlinked_shards = shard_dir.is_symlink()
    for path in sorted(shard_dir.iterdir()) if shard_dir.is_dir() and not plan.symlinked_shards else []:
        # only files named as the format names shards (or their temp files), never through a symlink
        if path.name in listed or not COLLECTABLE.fullmatch(path.name) or path.is_symlink() or not path.is_file():
            continue
        if path.name in of_dropped or now - path.stat().st_mtime >= retention_s:
            plan.dropped_shards.append((path.name, path.stat().st_size))
        else:
            plan.window_kept_shards += 1
    plan.dropped_segments = unlisted_segments(root, [current] + [load_manifest(root, version=v)
                                                                 for v in plan.kept_versions], now - retention_s,
                                              plan.dropped_versions)
    have = set(versions)
    vdir = root / VERSIONS_DIR
    head = versions[-1] if versions else 0
    plan.leftover_dirs = [f"{VERSIONS_DIR}/{d.name}" for d in (sorted(vdir.iterdir()) if vdir.is_dir() else [])
                          if d.is_dir() and not d.is_symlink() and re.fullmatch(r"v\d{6,}", d.name) and int(d.name[1:]) not in have
                          and int(d.name[1:]) < head]
    plan.dropped_stats = unused_stats_entries(root, plan.kept_versions or [None])
    return plan


def unlisted_segments(root: Path, kept: list[dict], before: float, dropped: list[int]) -> list[tuple[str, int]]:
    """Files in segments/ (format 4) no kept manifest lists, that gc may delete: (name, bytes).

    A segment is shared by every version that lists it, so one is deleted only when no kept version
    does, and it either was written before the retention window or a dropped version listed it (a
    newer one may be a running write's, not yet committed).

    Args:
        root: the dataset root.
        kept: the manifests of the versions gc keeps (the current one among them).
        before: epoch seconds: an unlisted segment written before this is an old leftover.
        dropped: the versions gc deletes.
    """
    folder = root / SEGMENTS_DIR
    if not folder.is_dir() or folder.is_symlink():
        return []
    listed = {rel.split("/", 1)[1] for m in kept for _, rel in record_paths(m) if rel.startswith(f"{SEGMENTS_DIR}/")}
    of_dropped = {rel.split("/", 1)[1] for v in dropped for _, rel in record_paths(load_manifest(root, version=v))
                  if rel.startswith(f"{SEGMENTS_DIR}/")}
    out = []
    for path in sorted(folder.iterdir()):
        if path.name in listed or not SEGMENT_FILE.fullmatch(path.name) or path.is_symlink() or not path.is_file():
            continue
        if path.name in of_dropped or path.stat().st_mtime < before:
            out.append((path.name, path.stat().st_size))
    return out


def unused_stats_entries(root: Path, versions: list) -> list[tuple[str, int]]:
    """Entries of the `htdata stats` cache whose episode no kept version holds (name, bytes)."""

    cache = root / STATS_DIR
    if not cache.is_dir():
        return []
    used = set()
    for v in versions:
        with DatasetReader(root, version=v) as reader:
            used |= {f"{episode_key(reader, pos)}.json" for pos in range(len(reader.episodes))}
    return [(p.name, p.stat().st_size) for p in sorted(cache.iterdir()) if p.is_file() and p.name not in used]


def check_retention(retention_s: float, force: bool) -> None:
    if retention_s < 0:
        raise ArgumentError(f"--retention must be >= 0, got {retention_s:g} s")
    if retention_s < FORCE_BELOW_S and not force:
        raise RetentionTooShort(
            f"--retention {format_duration(retention_s)} is shorter than {format_duration(FORCE_BELOW_S)}: a reader "
            f"(a training job) that opened a version now collected will fail with VersionCollected on its next read; "
            f"add --force if no job reads an old version")


def collect(root, keep_versions: int, dry_run: bool, command: str, retention_s: float = DEFAULT_RETENTION_S,
            force: bool = False) -> GcPlan:
    """Plan (and unless dry_run, carry out) a gc of the dataset at `root`."""
    root = Path(root)
    check_retention(retention_s, force or dry_run)
    with WriterLock(root, command):
        plan = plan_gc(root, keep_versions, retention_s)
        if dry_run:
            return plan
        current = {s["name"] for s in version_shards(root, load_manifest(root))}
        doomed = {name for name, _ in plan.dropped_shards}
        if current & doomed:    # never: plan_gc keeps the current version's shards
            raise RuntimeError(f"gc would delete shards of the current version: {sorted(current & doomed)[:3]}")
        if current_version(root) in plan.dropped_versions:
            raise RuntimeError("gc would delete the current version")
        record = {"time": _iso(time.time()), "command": command, "retention": format_duration(retention_s)}
        for v in plan.dropped_versions:
            # the tombstone first: a reader that finds a file gone learns why
            write_bytes_atomic(root / tombstone_file(v), (json.dumps({"version": v, **record}) + "\n").encode())
            (root / version_manifest_file(v)).unlink(missing_ok=True)
            crash_point("gc_version_deleted")
            shutil.rmtree(root / version_dir(v), ignore_errors=True)
            crash_point("gc_version_files_deleted")
        for rel in plan.leftover_dirs:
            shutil.rmtree(root / rel, ignore_errors=True)
        for name in sorted(doomed):
            path = root / SHARDS_DIR / name
            if COLLECTABLE.fullmatch(name) and not path.is_symlink() and not path.parent.is_symlink():
                path.unlink(missing_ok=True)
        for name, _ in plan.dropped_segments:
            (root / SEGMENTS_DIR / name).unlink(missing_ok=True)
        for name, _ in plan.dropped_stats:
            (root / STATS_DIR / name).unlink(missing_ok=True)
        return plan
