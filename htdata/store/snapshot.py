"""Open a version of a dataset as a Snapshot, and commit a new version from parts.

Every command that writes a dataset (ingest, rm, trim, merge, split,
renormalise) does the same three things: open the current version (the
parent), build the new version's parts (reusing the parent's untouched ones),
and `commit_parts`; htdata/write/newversion.py (`NewVersion`) is their one
owner, with the writer lock around them and the clean-up of a failed write.
`commit_parts` checks that every shard it lists is on disk with its recorded
size, validates the episode records, computes the change against the
parent, and hands the files to `versions.write_version`, which links the
version file into place (the commit). The caller holds the writer lock.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from htdata import __version__
from htdata.errors import DatasetError
from htdata.format.mapstorage import hand_present
from htdata.format.table import EPISODES_FILE, FORMAT, FORMAT_VERSION, HANDS, MANIFEST_FILE, SHARDS_DIR
from htdata.glove.calibration import carried_digests, merge_calibrations
from htdata.resources import validate_json
from htdata.store import storage
from htdata.store.manifest import load_index, load_manifest, load_records
from htdata.store.parts import Part, assemble, parts_of_version, unit_of_shard
from htdata.store.segments import segment_parts, segmented, write_segments
from htdata.store.splitfiles import carried_splits
from htdata.store.versions import change_record, current_version, diff_episodes, now_utc, summarise, write_version

SplitMaker = Callable[[list[dict], str], dict[str, bytes]]
# Manifest fields a new version inherits from its parent unless the writer sets them.
CARRIED_FIELDS = ("sources", "layouts", "canonical", "codec")


@dataclass
class Snapshot:
    """One committed version: its manifest (with its shard list), episode records and index (loaded on first use)."""
    root: Path
    manifest: dict
    episodes: list[dict]
    stored: dict | None = None        # the manifest as the version file holds it (None: `manifest`)
    _index: np.ndarray | None = field(default=None, repr=False)

    @property
    def version(self) -> int | None:
        return self.manifest.get("version")

    @property
    def index(self) -> np.ndarray:
        """The version's index rows (INDEX_DTYPE), memory-mapped or assembled from its segments on first use."""
        if self._index is None:
            self._index = load_index(self.root, mmap=True, manifest=self.stored or self.manifest)
        return self._index

    def parts(self) -> list[Part]:
        """The version's work units as Parts (htdata/store/parts.py), what a writer carries or re-packs.

        A segmented version (format 4) gives them from its segments, without the global index.

        Returns:
            One Part per unit, in shard order.
        """
        if self.stored is not None and segmented(self.stored):
            return segment_parts(self.root, self.stored)
        return parts_of_version(self.manifest, self.episodes, self.index)

    def episode_ids(self) -> list[str]:
        """The version's episode ids.

        Returns:
            The ids, in the version's episode order.
        """
        return [e["episode_id"] for e in self.episodes]

    def next_unit(self) -> int:
        """First work-unit number no version of this dataset has used (shard names stay unique).

        Returns:
            The larger of the manifest's `next_unit` and one past its highest shard's unit.
        """
        used = [unit_of_shard(s["name"]) for s in self.manifest["shards"]]
        return max([int(self.manifest.get("next_unit", 0))] + [u + 1 for u in used])


def open_snapshot(root: str | os.PathLike, version: int | None = None) -> Snapshot:
    """The current version (or `version`) of the committed dataset at `root`.

    Args:
        root: the dataset root, a local path or an fsspec URL.
        version: the version to open (None: the current one).

    Returns:
        Its Snapshot (the index read on first use).

    Raises:
        FileNotFoundError: no such version (or no dataset) at `root`.
        ValueError: a manifest, episode file or index that does not read (DatasetStateError, DatasetError).
    """
    stored = load_manifest(root, version=version)
    manifest, episodes = load_records(root, stored)
    return Snapshot(root=Path(root), manifest=manifest, episodes=episodes, stored=stored)


def current_snapshot(root: str | os.PathLike) -> Snapshot | None:
    """The current version, or None when `root` holds no committed dataset.

    A folder with committed version files is a dataset even when dataset.json
    is missing or damaged (the pointer is a cache of the newest version file).

    Args:
        root: the dataset root, a local path or an fsspec URL.

    Returns:
        The current version's Snapshot, or None.
    """

    if current_version(root) is None and not storage.exists(storage.join(root, MANIFEST_FILE)):
        return None
    return open_snapshot(root)


def _frames_per_hand(rows: np.ndarray) -> dict[str, int]:
    return {hand: int(np.count_nonzero(hand_present(rows, hand))) for hand in HANDS}   # maps stored or not


def _index_sha256(rows: np.ndarray) -> str:
    """The sha256 of the global index as np.save writes it: what a reader's assembly must give back."""
    buf = io.BytesIO()
    np.save(buf, rows, allow_pickle=False)
    return hashlib.sha256(buf.getvalue()).hexdigest()


def _check_shards_on_disk(root: Path, shards: list[dict]) -> None:
    for entry in shards:
        path = root / SHARDS_DIR / entry["name"]
        if not path.is_file():
            raise FileNotFoundError(f"{path}: shard listed by a work unit is missing")
        if path.stat().st_size != entry["bytes"]:
            raise DatasetError(f"{path}: size {path.stat().st_size} != recorded {entry['bytes']}")


def commit_parts(root: str | os.PathLike, parts: list[Part], fields: dict, parent: Snapshot | None,
                 command: str, splits: SplitMaker | None = None, next_unit: int | None = None,
                 created: str | None = None, htdata_version: str | None = None) -> dict:
    """Write a new version made of `parts`; returns its manifest. Only write/ calls it (NewVersion), holding
    the writer lock.

    Args:
        root: the dataset root (local).
        parts: the new version's work units, carried or new, in order.
        fields: sources / layouts / canonical / codec (missing ones: the parent's) and new "calibrations" (the
            parent's are kept for the episodes that still name them, glove.calibration.merge_calibrations).
        parent: the version this one is built on (None: the first).
        command: the command line, kept in the version's change record.
        splits: `splits(episodes, episodes_sha256)` -> {name: split file bytes} (None: the parent's, carried:
            htdata/curate/splitversions.py).
        next_unit: the first unit number free after this version (at least past every listed shard).
        created: the version's time (None: now, UTC).
        htdata_version: the writer's version string (None: this htdata's).

    Returns:
        The committed manifest as a reader sees it: versions/vN.json's, with the shard list its segments hold.

    Raises:
        FileNotFoundError: a listed shard is missing.
        DatasetError: a listed shard's size differs from its record.
        ValueError: an episode names a layout or calibration not provided; a record or the manifest
            does not match its schema.
        RuntimeError: the parent is no longer the current version (store/versions.write_version).
        FileExistsError: the version file exists already.
    """
    root = Path(root)
    built = assemble(parts)
    _check_shards_on_disk(root, built.shards)
    layouts = {**(parent.manifest["layouts"] if parent else {}), **fields.get("layouts", {})}
    for ep, unchecked in zip(built.episodes, built.unchecked):
        if unchecked:   # a record its maker checked (Part.records_checked) is not checked twice
            validate_json(ep, "episode", where=f"{EPISODES_FILE}: episode {ep.get('episode_id')!r}")
        for hand, layout_id in ep["layouts"].items():
            if layout_id not in layouts:
                raise ValueError(f"episode {ep['episode_id']!r}: layout {layout_id!r} ({hand}) not provided to commit")
    used_layouts = {lid for ep in built.episodes for lid in ep["layouts"].values()}
    episodes_bytes = "".join(json.dumps(ep, sort_keys=True) + "\n" for ep in built.episodes).encode()
    carried = {k: fields[k] if k in fields else (parent.manifest[k] if parent else None) for k in CARRIED_FIELDS}
    carried["layouts"] = {k: v for k, v in layouts.items() if k in used_layouts}
    used_calibrations = {cid for ep in built.episodes for cid in ep.get("calibration", {}).values()}
    calibrations = merge_calibrations(parent.manifest.get("calibrations", {}) if parent else {},
                                      fields.get("calibrations", {}), used_calibrations)
    unknown = used_calibrations - set(calibrations)
    if unknown:
        raise ValueError(f"calibration(s) {sorted(unknown)} named by episode records but not provided to commit")
    diff = diff_episodes(parent.episodes if parent else [], built.episodes)
    time = created or now_utc()
    manifest = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "created": time,
        "htdata_version": htdata_version or __version__, **carried, "calibrations": calibrations,
        "tasks": sorted({ep["task"] for ep in built.episodes}),
        "scenes": sorted({ep["scene"] for ep in built.episodes}),
        "counts": {"episodes": len(built.episodes), "samples": int(len(built.rows)),
                   "shards": len(built.shards), "frames_per_hand": _frames_per_hand(built.rows)},
        "segments": [],     # written below, once the manifest has been checked
        "episodes_sha256": hashlib.sha256(episodes_bytes).hexdigest(),
        "index_sha256": _index_sha256(built.rows),
        "record_digests": carried_digests(built.episodes),   # what a record of this version may not lack
        "parent": parent.version if parent else None,
        "next_unit": max([next_unit or 0, parent.next_unit() if parent else 0]
                         + [unit_of_shard(s["name"]) + 1 for s in built.shards]),
        "change": change_record(command, summarise(diff), time),
    }
    # the version number and its split files are filled in by write_version; validate the rest with placeholders
    validate_json({**manifest, "version": (manifest["parent"] or 0) + 1, "splits": {}}, "manifest",
                  where=str(root / MANIFEST_FILE))
    if splits is None:
        splits = (lambda eps, sha: carried_splits(parent, eps, sha)) if parent else (lambda eps, sha: {})
    split_files = splits(built.episodes, manifest["episodes_sha256"])
    # segments an earlier version wrote are named by their bytes and not written again (store/segments.py)
    manifest["segments"], _ = write_segments(root, parts, built.episodes)
    return {**write_version(root, manifest, split_files), "shards": built.shards}
