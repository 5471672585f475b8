"""DatasetMetadata: what one committed version says about itself, without reading a sample.

The records of a version: its manifest (layouts, canonical template, codec,
calibrations, tasks, scenes, shards, splits), episodes.jsonl, index.npy, the
split files and the coverage / region PNGs they name. Everything a trainer
or a command needs to choose samples (episode ranges, split -> sample
indices, a layout's coverage, the region map) is answered from these; no
shard is ever opened here (that is htdata/read/reader.py's job, which builds
on this object: `reader.meta`). As LeRobot keeps LeRobotDatasetMetadata
beside LeRobotDataset.

The index is loaded on first use (memory-mapped when local, one download
into the cache when remote; a format 4 version's assembled from its segments,
a large one once into the local cache and mapped). Pickling drops a mapped
index (it reloads on first use) and keeps one held in memory.

Errors a caller causes (an unknown version, split, part, episode or layout,
a position out of range) are htdata.errors.ArgumentError; each is also the
built-in type callers caught before (FileNotFoundError, KeyError,
IndexError). Records that disagree with each other are DatasetError.
"""

from __future__ import annotations

import hashlib
import json
import os
from contextlib import contextmanager

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.format.codec import decode_png_u8
from htdata.format.table import HANDS, LAYOUTS_DIR, SPLITS_DIR
from htdata.store import storage
from htdata.store.confine import inside
from htdata.store.gcrecord import VersionCollected, collected_error
from htdata.store.manifest import load_index, load_manifest, load_records
from htdata.store.remote import load_cached_index
from htdata.store.segments import segmented
from htdata.store.splitfiles import SplitRejected, parse_split_doc
from htdata.store.versions import list_versions


class NoSuchVersion(ArgumentError, FileNotFoundError):
    """A version number the dataset never committed (`htdata log` lists those it has)."""


class NoSuchSplit(ArgumentError, FileNotFoundError):
    """A split name this version does not have (`htdata split` makes one)."""


class NotInVersion(ArgumentError, KeyError):
    """An episode id, layout id or split part this version does not have."""

    __str__ = ArgumentError.__str__   # the message as written, not KeyError's repr of it


class OutOfRange(ArgumentError, IndexError):
    """A sample, episode or frame position outside what the version holds."""


@contextmanager
def collected_guard(root: str, version: int | None, where: str | None = None):
    """Turn a file gone because `htdata gc` collected the version into one VersionCollected error.

    Args:
        root: the dataset root (path or URL).
        version: the version being read (None: the unversioned dataset).
        where: the file to name (default: the missing file's own name).

    Raises:
        VersionCollected: the file is gone and a gc tombstone names the version.
    """
    try:
        yield
    except FileNotFoundError as exc:
        gone = collected_error(root, version, where or exc.filename)
        if gone is None:
            raise
        raise gone from None


class DatasetMetadata:
    """The records of one committed version: manifest, episodes, index, splits, layouts (never a sample).

    Args:
        root: the dataset root, a local path or an fsspec URL (file://, memory://, s3://...).
        version: the version to open (`htdata log` lists them); None: the current one.
        validate_manifest: check the manifest against schemas/manifest.schema.json.

    Raises:
        NoSuchVersion: `version` is not a committed version of the dataset.
        FileNotFoundError: `root` holds no committed dataset.
        DatasetError: episodes.jsonl and the manifest disagree on the number of episodes.
    """

    def __init__(self, root: str | os.PathLike, version: int | None = None, validate_manifest: bool = True):
        self.root = os.fspath(root)
        self.stored: dict = _load_manifest(self.root, version, validate_manifest)   # as the version file holds it
        self.version: int | None = self.stored.get("version")
        with collected_guard(self.root, self.version):
            # the manifest as format 3 held it (its shard list), whether stored so or as segments
            self.manifest, self.episodes = load_records(self.root, self.stored)
        if len(self.episodes) != self.manifest["counts"]["episodes"]:
            held = "its segments hold" if segmented(self.stored) else "episodes.jsonl has"
            raise DatasetError(f"{self.root}: {held} {len(self.episodes)} records, "
                               f"manifest counts {self.manifest['counts']['episodes']}")
        self.episode_ids: list[str] = [ep["episode_id"] for ep in self.episodes]
        self._episode_pos = {eid: i for i, eid in enumerate(self.episode_ids)}
        self._index: np.ndarray | None = None
        self._maps: dict[str, np.ndarray] = {}

    def __getstate__(self):
        state = self.__dict__.copy()
        if isinstance(state["_index"], np.memmap):
            state["_index"] = None      # a memory map: reopened on first use
        # (an index assembled in memory from a version's segments travels along: a worker would assemble it again)
        return state

    # -- counts and vocabularies ------------------------------------------
    @property
    def num_samples(self) -> int:
        """Samples (frames) in the version: rows of index.npy."""
        return int(self.manifest["counts"]["samples"])

    @property
    def num_episodes(self) -> int:
        """Episodes in the version: records of episodes.jsonl."""
        return len(self.episodes)

    @property
    def tasks(self) -> list[str]:
        """Task names; an item's `task` id is a position in this list."""
        return list(self.manifest.get("tasks", []))

    @property
    def scenes(self) -> list[str]:
        """Scene names; an item's `scene` id is a position in this list."""
        return list(self.manifest.get("scenes", []))

    @property
    def hands(self) -> tuple[str, ...]:
        """The hands (of "left", "right") at least one episode has a glove on."""
        have = {hand for ep in self.episodes for hand in ep.get("hands", ())}
        return tuple(h for h in HANDS if h in have)

    @property
    def layout_ids(self) -> list[str]:
        """Ids of the glove layouts the version lists (sorted)."""
        return sorted(self.manifest["layouts"])

    @property
    def shard_names(self) -> list[str]:
        """File names under shards/ of the version's shards, in shard-number order."""
        return [s["name"] for s in self.manifest["shards"]]

    @property
    def codec(self) -> dict:
        """The manifest's codec record (how each member kind is encoded)."""
        return self.manifest["codec"]

    # -- index and episodes -----------------------------------------------
    @property
    def index(self) -> np.ndarray:
        """The index rows (format.table.INDEX_DTYPE): index.npy memory-mapped when local, cached once when remote;
        a segmented version's assembled from its segments (htdata/store/segments.py).

        Raises:
            DatasetError: the index has another number of rows than the manifest counts.
        """
        if self._index is None:
            if storage.is_url(self.root) and not segmented(self.stored):
                rows = load_cached_index(self.root, self.manifest)   # one download, keyed by sha256, then mmap
            else:
                with collected_guard(self.root, self.version):
                    rows = load_index(self.root, mmap=True, manifest=self.stored)
            if len(rows) != self.num_samples:
                raise DatasetError(f"{self.root}: index has {len(rows)} rows, manifest counts {self.num_samples}")
            self._index = rows
        return self._index

    def episode_position(self, episode: str | int) -> int:
        """Position in episodes.jsonl of an episode.

        Args:
            episode: an episode id, or a position (returned when in range).

        Raises:
            OutOfRange: a position outside 0..num_episodes-1.
            NotInVersion: an id the version does not have.
        """
        if isinstance(episode, (int, np.integer)):
            if not 0 <= episode < len(self.episodes):
                raise OutOfRange(f"{self.root}: episode position {episode} out of range ({len(self.episodes)})")
            return int(episode)
        if episode not in self._episode_pos:
            raise NotInVersion(f"{self.root}: no episode {episode!r}")
        return self._episode_pos[episode]

    def episode_range(self, episode: str | int) -> tuple[int, int]:
        """(first global sample, number of frames) of an episode.

        Args:
            episode: an episode id or position.
        """
        ep = self.episodes[self.episode_position(episode)]
        return int(ep["first_sample"]), int(ep["num_frames"])

    def locate(self, episode: str | int, frame: int) -> int:
        """Global sample index of one frame of one episode.

        Args:
            episode: an episode id or position.
            frame: the frame within the episode (0-based).

        Raises:
            OutOfRange: the episode has no such frame.
        """
        first, n = self.episode_range(episode)
        if not 0 <= frame < n:
            raise OutOfRange(f"{self.root}: episode {self.episodes[self.episode_position(episode)]['episode_id']!r} "
                             f"has frames 0..{n - 1}, asked for {frame}")
        return first + int(frame)

    # -- layouts and maps -------------------------------------------------
    def _png(self, relpath: str) -> np.ndarray:
        if relpath not in self._maps:
            path = inside(self.root, relpath)
            self._maps[relpath] = decode_png_u8(storage.read_bytes(path), path)
        return self._maps[relpath]

    def coverage(self, layout_id: str) -> np.ndarray:
        """(224,224) uint8 0/1: where a glove layout has sensors.

        Args:
            layout_id: one of `layout_ids`.

        Raises:
            NotInVersion: the version lists no such layout.
        """
        return self._png(self._layout_entry(layout_id)["coverage"])

    def layout(self, layout_id: str) -> dict:
        """The layout document (schemas/layout.schema.json) the version stores for a glove layout.

        Args:
            layout_id: one of `layout_ids`.

        Raises:
            NotInVersion: the version lists no such layout.
        """
        return json.loads(storage.read_text(inside(self.root, self._layout_entry(layout_id)["file"])))

    def _layout_entry(self, layout_id: str) -> dict:
        layouts = self.manifest["layouts"]
        if layout_id not in layouts:
            raise NotInVersion(f"{self.root}: layout {layout_id!r} not in dataset (has {sorted(layouts)})")
        return layouts[layout_id]

    @property
    def region_map(self) -> np.ndarray:
        """(224,224) uint8 PART ids (thumb=1..palm=6, 0 outside): the stage-2 masking map."""
        return self._png(self.manifest["canonical"].get("parts", f"{LAYOUTS_DIR}/parts.png"))

    @property
    def place_map(self) -> np.ndarray:
        """(224,224) uint8 per-place region ids of the canonical template."""
        return self._png(self.manifest["canonical"]["regions"])

    # -- splits -----------------------------------------------------------
    def split(self, name: str) -> dict:
        """Split `name` of this version: {"parts": {part: {"episodes": [...]}, ...}, ...}.

        A versioned dataset keeps each version's splits with it (manifest "splits"); an
        unversioned one has DATASET/splits/NAME.json.

        Args:
            name: the split's name (`htdata split --name`).

        Raises:
            NoSuchSplit: the version has no split of that name.
            SplitRejected: the split file's sha256 differs from the manifest's, or its parts overlap.
        """
        if "version" in self.manifest:
            entry = self.manifest.get("splits", {}).get(name)
            if entry is None:
                raise NoSuchSplit(f"{self.root}: version {self.version} has no split named {name!r} "
                                  f"(splits: {sorted(self.manifest.get('splits', {})) or 'none'}; "
                                  f"run `htdata split`)")
            path = inside(self.root, entry["file"], f"splits.{name}.file")
            with collected_guard(self.root, self.version, path):
                data = storage.read_bytes(path)
            # what `htdata validate` checks that would silently skew a training run, checked once here too
            if hashlib.sha256(data).hexdigest() != entry["sha256"]:
                raise SplitRejected(f"{path}: sha256 differs from version {self.version}'s manifest (edited "
                                    f"after it was committed?); re-make it with `htdata split --name {name}`")
        else:
            path = storage.join(self.root, f"{SPLITS_DIR}/{name}.json")
            if not storage.exists(path):
                raise NoSuchSplit(f"{path}: no split named {name!r} (run `htdata split`)")
            data = storage.read_bytes(path)
        return parse_split_doc(data, path, name)

    def episode_positions(self, split: str | None = None, part: str | None = None) -> list[int]:
        """Positions (ascending) of the episodes a split part selects.

        Args:
            split: a split name; None selects every episode.
            part: the part of `split` ("train", "test", ...); required with a split, refused without.

        Raises:
            ArgumentError: a part without a split, or a split without a part.
            NoSuchSplit: the version has no such split.
            NotInVersion: the split has no such part.
            DatasetError: the split names episodes the version does not have.
        """
        if split is None:
            if part is not None:
                raise ArgumentError(f"part {part!r} given without a split")
            return list(range(len(self.episodes)))
        parts = self.split(split)["parts"]
        if part is None:
            raise ArgumentError(f"split {split!r}: choose a part from {sorted(parts)}")
        if part not in parts:
            raise NotInVersion(f"split {split!r} has no part {part!r} (parts: {sorted(parts)})")
        ids = parts[part]["episodes"]
        missing = [e for e in ids if e not in self._episode_pos]
        if missing:
            raise DatasetError(f"{self.root}: split {split!r}/{part}: unknown episode(s) {missing[:5]}")
        return sorted(self._episode_pos[e] for e in ids)

    def sample_indices(self, split: str | None = None, part: str | None = None) -> np.ndarray:
        """Global sample indices (int64, ascending) of the episodes a split part selects.

        Args:
            split: a split name; None selects every episode.
            part: the part of `split`; required with a split.

        Raises:
            As `episode_positions`.
        """
        ranges = [self.episode_range(p) for p in self.episode_positions(split, part)]
        if not ranges:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([np.arange(a, a + n, dtype=np.int64) for a, n in ranges])


def _load_manifest(root: str, version: int | None, validate: bool) -> dict:
    """load_manifest, with "no such version" an ArgumentError (a collected version stays VersionCollected)."""
    try:
        return load_manifest(root, validate=validate, version=version)
    except VersionCollected:
        raise
    except FileNotFoundError as exc:
        if version is not None and int(version) not in list_versions(root):
            raise NoSuchVersion(str(exc)) from None
        raise
