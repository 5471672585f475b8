"""DatasetReader: random access, windows and streaming over a committed dataset.

Random access never scans: index.npy gives each sample's shard, header
offset and member sizes, so one seek + one read returns exactly that
sample's bytes. Each member's header is checked cheaply (name and size
fields compared as bytes, docs/FORMAT.md "Tar is USTAR") so an index that disagrees
with its shard is an error naming the sample; full header parsing and
checksums are `htdata validate`'s job, not the hot path's.
Works on local paths and fsspec URLs (file://, memory://, s3://...).

Hot-path costs kept small on purpose (see htdata/benchmarks/loader.py):
index rows are read as one tuple (`np.void.item()`), not field by field;
.npy members skip np.load's header parsing once a header has been seen
(codec.decode_npy). Member names, sizes and codecs come from htdata/format/table.py.

Shard file handles are opened lazily and remembered with the pid that opened
them; after a fork (DataLoader workers) the child opens its own. Pickling a
reader drops handles and the index map; they reopen on first use.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

from htdata.store import storage
from htdata.store.confine import inside
from htdata.store.splitfiles import SplitRejected, parse_split_doc  # noqa: F401 (SplitRejected: its old home)
from htdata.format.codec import decode_png_u8
from htdata.format.mapstorage import MapStorage
from htdata.format.table import (HANDS, INDEX_DTYPE, JSON_MEMBER, LAYOUTS_DIR, MEMBER_ORDER, SHARDS_DIR, SIZE_FIELDS,
                                 SPLITS_DIR, decode_sample, raw_member, tactile_member)
from htdata.store.manifest import load_episodes, load_index, load_manifest
from htdata.format.shardio import BLOCK, describe_header, header_matches, padded, sample_key
from htdata.store.remote import load_cached_index
from htdata.store.gcrecord import collected_error
from htdata.read.rawstream import RawMapRenderer, check_records

MAX_OPEN_SHARDS = 128   # an LRU of open shard files; one-episode units make many small shards
_SIZE_POS = tuple(INDEX_DTYPE.names.index(SIZE_FIELDS[s]) for s in MEMBER_ORDER)


class SampleRow(NamedTuple):
    """One index.npy row as plain ints; `sizes` follows format.MEMBER_ORDER (0 = absent)."""
    shard: int
    offset: int
    episode: int
    frame: int
    sizes: tuple[int, ...]


def member_layout(sizes: tuple[int, ...], wanted=None) -> tuple[list[tuple[str, int, int]], int]:
    """([(suffix, header offset from the first header, size)], bytes to read).

    Only members present (size > 0) and in `wanted` (all when None) are
    listed; the read stops at the end of the last listed member.
    """
    layout, pos, end = [], 0, 0
    for suffix, size in zip(MEMBER_ORDER, sizes):
        if size:
            if wanted is None or suffix in wanted:
                layout.append((suffix, pos, size))
                end = pos + BLOCK + size
            pos += BLOCK + padded(size)
    return layout, end


class DatasetReader:
    def __init__(self, root: str | os.PathLike, validate_manifest: bool = True, version: int | None = None):
        """Open the current version of the dataset at `root`, or version `version` (htdata log lists them)."""
        self.root = os.fspath(root)
        self.manifest = load_manifest(self.root, validate=validate_manifest, version=version)
        self.version: int | None = self.manifest.get("version")
        with self._collected_guard():
            self.episodes: list[dict] = load_episodes(self.root, self.manifest)
        if len(self.episodes) != self.manifest["counts"]["episodes"]:
            raise ValueError(f"{self.root}: episodes.jsonl has {len(self.episodes)} records, "
                             f"manifest counts {self.manifest['counts']['episodes']}")
        check_records(self)     # calibration ids and fit digests recomputed (htdata.read.rawstream)
        self._episode_pos = {ep["episode_id"]: i for i, ep in enumerate(self.episodes)}
        self._episode_ids = [ep["episode_id"] for ep in self.episodes]
        self._shard_names = [s["name"] for s in self.manifest["shards"]]
        self._n = int(self.manifest["counts"]["samples"])
        self._index: np.ndarray | None = None
        self._handles: OrderedDict[int, object] = OrderedDict()
        self._pid = os.getpid()
        self._maps: dict[str, np.ndarray] = {}
        # a version that does not store its maps: decoded samples get them rendered from the raw rows
        self._renderer = None if MapStorage.of(self.manifest).stores_maps else RawMapRenderer(self)

    @contextmanager
    def _collected_guard(self, where: str | None = None):
        """A file of this version that is gone because `htdata gc` collected the version: VersionCollected."""
        try:
            yield
        except FileNotFoundError as exc:
            gone = collected_error(self.root, getattr(self, "version", None), where or exc.filename)
            if gone is None:
                raise
            raise gone from None

    # -- pickling / fork safety -------------------------------------------
    def __getstate__(self):
        state = self.__dict__.copy()
        state["_index"] = None
        state["_handles"] = OrderedDict()
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._pid = os.getpid()

    def _check_pid(self) -> None:
        if os.getpid() != self._pid:
            # Inherited handles share file offsets with the parent: never use them.
            self._handles = OrderedDict()
            self._pid = os.getpid()

    def close(self) -> None:
        if os.getpid() == self._pid:
            for handle in self._handles.values():
                handle.close()
        self._handles.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- index -------------------------------------------------------------
    @property
    def index(self) -> np.ndarray:
        if self._index is None:
            if storage.is_url(self.root):
                # Remote: one download into the local cache (keyed by sha256), then mmap.
                rows = load_cached_index(self.root, self.manifest)
            else:
                with self._collected_guard():
                    rows = load_index(self.root, mmap=True, manifest=self.manifest)
            if len(rows) != self._n:
                raise ValueError(f"{self.root}: index has {len(rows)} rows, manifest counts {self._n}")
            self._index = rows
        return self._index

    def __len__(self) -> int:
        return self._n

    def row(self, i: int) -> SampleRow:
        """Index row of sample `i` (negative counts from the end) as plain ints."""
        n = self._n
        if not -n <= i < n:
            raise IndexError(f"{self.root}: sample {i} out of range (dataset has {n})")
        values = self.index[int(i) % n].item()   # one tuple: ~10x cheaper than field-by-field
        return SampleRow(values[0], values[1], values[2], values[3], tuple(values[p] for p in _SIZE_POS))

    def _key(self, row: SampleRow) -> str:
        return sample_key(self._episode_ids[row.episode], row.frame)

    def key(self, i: int) -> str:
        return self._key(self.row(i))

    def episode_position(self, episode: str | int) -> int:
        if isinstance(episode, (int, np.integer)):
            if not 0 <= episode < len(self.episodes):
                raise IndexError(f"{self.root}: episode position {episode} out of range ({len(self.episodes)})")
            return int(episode)
        if episode not in self._episode_pos:
            raise KeyError(f"{self.root}: no episode {episode!r}")
        return self._episode_pos[episode]

    def episode_range(self, episode: str | int) -> tuple[int, int]:
        """(first global sample, number of frames) of an episode id or position."""
        ep = self.episodes[self.episode_position(episode)]
        return int(ep["first_sample"]), int(ep["num_frames"])

    def locate(self, episode: str | int, frame: int) -> int:
        """Global sample index of (episode, frame)."""
        first, n = self.episode_range(episode)
        if not 0 <= frame < n:
            raise IndexError(f"{self.root}: episode {self.episodes[self.episode_position(episode)]['episode_id']!r} "
                             f"has frames 0..{n - 1}, asked for {frame}")
        return first + int(frame)

    # -- bytes -------------------------------------------------------------
    def _shard_path(self, shard: int, confined: bool = False) -> str:
        """shards/NAME of shard `shard`; `confined`: refused when it resolves outside the dataset (a symlink)."""
        if not 0 <= shard < len(self._shard_names):   # a damaged or hostile index row: one line, not IndexError
            raise ValueError(f"{self.root}: an index row names shard {shard}, but version {self.version} has "
                             f"{len(self._shard_names)} shards (index.npy damaged?); run `htdata validate`")
        rel = f"{SHARDS_DIR}/{self._shard_names[shard]}"
        return inside(self.root, rel, f"shards[{shard}]") if confined else storage.join(self.root, rel)

    def _handle(self, shard: int):
        self._check_pid()
        handle = self._handles.get(shard)
        if handle is None:
            with self._collected_guard(self._shard_path(shard)):
                handle = storage.open_binary(self._shard_path(shard, confined=True))
            self._handles[shard] = handle
            if len(self._handles) > MAX_OPEN_SHARDS:
                _, oldest = self._handles.popitem(last=False)
                oldest.close()
        else:
            self._handles.move_to_end(shard)
        return handle

    def _read_members(self, f, row: SampleRow, key: str, wanted=None) -> dict[str, bytes]:
        """One seek + one read of the sample's span, then the members sliced out of it."""
        layout, size = member_layout(row.sizes, wanted)
        if not layout:
            return {}
        f.seek(row.offset)
        span = f.read(size)
        if len(span) != size:
            raise ValueError(f"{self._shard_path(row.shard)}: truncated at sample {key} "
                             f"(wanted {size} B at {row.offset}, got {len(span)})")
        out = {}
        for suffix, rel, member_size in layout:
            header = span[rel:rel + BLOCK]
            expected = f"{key}.{suffix}"
            if not header_matches(header, expected.encode("utf-8"), member_size):
                raise ValueError(f"{self._shard_path(row.shard)}: at offset {row.offset + rel} expected member "
                                 f"{expected} ({member_size} B), found {describe_header(header)}: "
                                 f"index and shard disagree")
            out[suffix] = span[rel + BLOCK:rel + BLOCK + member_size]
        return out

    def sample(self, i: int, suffixes=None) -> dict[str, bytes]:
        """Raw member bytes of sample `i`, keyed by suffix ("json", "rgb.jpg", ...).

        `suffixes` limits the result to those members (absent ones are skipped);
        the read then stops after the last one wanted.
        """
        return self.read_sample(i, suffixes)[2]

    def read_sample(self, i: int, suffixes=None) -> tuple[SampleRow, str, dict[str, bytes]]:
        """(index row, key, members) of sample `i`: one index lookup for callers needing all three."""
        row = self.row(i)
        key = self._key(row)
        return row, key, self._read_members(self._handle(row.shard), row, key, suffixes)

    def decode(self, members: dict[str, bytes], where: str = "sample") -> dict:
        """Decode raw members (format.decode_sample): rgb uint8 (224,224,3), tactile/bend per hand, meta.

        "meta" is present only when the json member is (it always is in sample(i)).
        """
        return decode_sample(members, where)

    def decoded(self, i: int, suffixes=None) -> dict:
        """Sample `i` decoded (its `suffixes` only, when given). A version whose maps are not stored
        (htdata/format/mapstorage.py) gets each map rendered from the raw rows (+ json) it reads for it."""
        row, key, members = self.read_sample(i, self._members_to_read(suffixes))
        return self._decode_row(row, members, f"{self.root}: {key}", suffixes)

    def _members_to_read(self, suffixes):
        if self._renderer is None or suffixes is None:
            return suffixes
        hands = [h for h in HANDS if tactile_member(h) in suffixes]
        return tuple(suffixes) + ((JSON_MEMBER, *(raw_member(h) for h in hands)) if hands else ())

    def _decode_row(self, row: SampleRow, members: dict[str, bytes], where: str, suffixes) -> dict:
        """decode_sample of the members asked for, plus the maps rendered from raw rows when not stored."""
        asked = members if suffixes is None else {s: b for s, b in members.items() if s in suffixes}
        out = decode_sample(asked, where)
        if self._renderer is not None:
            for hand in HANDS:
                if raw_member(hand) in members and (suffixes is None or tactile_member(hand) in suffixes):
                    out["tactile"][hand] = self._renderer.render(row.episode, hand, members, where)
        return out

    def window(self, episode: str | int, frame: int, k: int) -> list[dict]:
        """Decoded frames T-k..T (k+1 frames) of one episode; never crosses its start."""
        if k < 0:
            raise ValueError(f"window size k must be >= 0, got {k}")
        end = self.locate(episode, frame)
        if frame - k < 0:
            eid = self.episodes[self.episode_position(episode)]["episode_id"]
            raise IndexError(f"{self.root}: window of frames {frame - k}..{frame} would cross the start "
                             f"of episode {eid!r} (frame 0); need frame >= {k}")
        return [self.decoded(i) for i in range(end - k, end + 1)]

    def iter_samples(self, shards: list[int] | None = None, decode: bool = False,
                     suffixes=None) -> Iterator[tuple[int, dict]]:
        """Stream (global index, members) shard by shard, each shard read front to back.

        `suffixes` limits which members are returned (and decoded), as in sample() and decoded().
        """
        rows = self.index
        for shard in (range(len(self._shard_names)) if shards is None else shards):
            entry = self.manifest["shards"][shard]
            first, count = int(entry["first_sample"]), int(entry["samples"])
            with storage.open_binary(self._shard_path(shard, confined=True)) as f:
                for i in range(first, first + count):
                    values = rows[i].item()
                    row = SampleRow(values[0], values[1], values[2], values[3],
                                    tuple(values[p] for p in _SIZE_POS))
                    if row.shard != shard:
                        raise ValueError(f"{self.root}: index row {i} names shard {row.shard}, "
                                         f"manifest puts it in {shard}")
                    key = self._key(row)
                    members = self._read_members(f, row, key, self._members_to_read(suffixes) if decode else suffixes)
                    yield i, (self._decode_row(row, members, f"{self.root}: {key}", suffixes) if decode else members)

    # -- layouts / maps ----------------------------------------------------
    def _png(self, relpath: str) -> np.ndarray:
        if relpath not in self._maps:
            path = inside(self.root, relpath)
            self._maps[relpath] = decode_png_u8(storage.read_bytes(path), path)
        return self._maps[relpath]

    def coverage(self, layout_id: str) -> np.ndarray:
        """(224,224) uint8 0/1: where this glove layout has sensors."""
        layouts = self.manifest["layouts"]
        if layout_id not in layouts:
            raise KeyError(f"{self.root}: layout {layout_id!r} not in dataset (has {sorted(layouts)})")
        return self._png(layouts[layout_id]["coverage"])

    def layout(self, layout_id: str) -> dict:
        if layout_id not in self.manifest["layouts"]:
            raise KeyError(f"{self.root}: layout {layout_id!r} not in dataset")
        return json.loads(storage.read_text(inside(self.root, self.manifest["layouts"][layout_id]["file"])))

    @property
    def region_map(self) -> np.ndarray:
        """(224,224) uint8 PART ids (thumb=1..palm=6, 0 outside): the stage-2 masking map."""
        canonical = self.manifest["canonical"]
        return self._png(canonical.get("parts", f"{LAYOUTS_DIR}/parts.png"))

    @property
    def place_map(self) -> np.ndarray:
        """(224,224) uint8 per-place region ids of the canonical template."""
        return self._png(self.manifest["canonical"]["regions"])

    # -- splits ------------------------------------------------------------
    def split(self, name: str) -> dict:
        """Split NAME of this version: {"parts": {part: {"episodes": [...]}, ...}, ...}.

        A versioned dataset keeps each version's splits with it (manifest "splits"); an
        unversioned one has DATASET/splits/NAME.json.
        """
        if "version" in self.manifest:
            entry = self.manifest.get("splits", {}).get(name)
            if entry is None:
                raise FileNotFoundError(f"{self.root}: version {self.version} has no split named {name!r} "
                                        f"(splits: {sorted(self.manifest.get('splits', {})) or 'none'}; "
                                        f"run `htdata split`)")
            path = inside(self.root, entry["file"], f"splits.{name}.file")
        else:
            path = storage.join(self.root, f"{SPLITS_DIR}/{name}.json")
        if not storage.exists(path):
            raise FileNotFoundError(f"{path}: no split named {name!r} (run `htdata split`)")
        data = storage.read_bytes(path)
        # what `htdata validate` checks that would silently skew a training run, checked once here too
        if "version" in self.manifest and hashlib.sha256(data).hexdigest() != entry["sha256"]:
            raise SplitRejected(f"{path}: sha256 differs from version {self.version}'s manifest (edited after "
                                f"it was committed?); re-make it with `htdata split --name {name}`")
        return parse_split_doc(data, path, name)

    def episode_positions(self, split: str | None = None, part: str | None = None) -> list[int]:
        """Episode positions selected by a split part (all episodes when split is None)."""
        if split is None:
            if part is not None:
                raise ValueError("part given without a split")
            return list(range(len(self.episodes)))
        parts = self.split(split)["parts"]
        if part is None:
            raise ValueError(f"split {split!r}: choose a part from {sorted(parts)}")
        if part not in parts:
            raise KeyError(f"split {split!r} has no part {part!r} (parts: {sorted(parts)})")
        ids = parts[part]["episodes"]
        missing = [e for e in ids if e not in self._episode_pos]
        if missing:
            raise KeyError(f"split {split!r}/{part}: unknown episode(s) {missing[:5]}")
        return sorted(self._episode_pos[e] for e in ids)

    def sample_indices(self, split: str | None = None, part: str | None = None) -> np.ndarray:
        """Global sample indices of the selected episodes, in global order."""
        ranges = [self.episode_range(p) for p in self.episode_positions(split, part)]
        if not ranges:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([np.arange(a, a + n, dtype=np.int64) for a, n in ranges])
