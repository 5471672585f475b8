"""DatasetReader: random access, windows and streaming over the samples of a committed version.

What the version says about itself (manifest, episodes, index, splits,
coverage, region maps) is its DatasetMetadata (htdata/read/metadata.py),
`reader.meta`; the reader answers the same names by handing them on, and
adds the samples.

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

import functools
import os
from collections import OrderedDict
from collections.abc import Iterator

from htdata._moved import moved_name
from htdata.errors import ArgumentError, DatasetError
from htdata.format.mapstorage import MapStorage
from htdata.format.shardio import BLOCK, describe_header, header_matches, sample_key
from htdata.format.table import (
    HANDS,
    INDEX_DTYPE,
    JSON_MEMBER,
    MEMBER_ORDER,
    SHARDS_DIR,
    SIZE_FIELDS,
    decode_sample,
    raw_member,
    tactile_member,
)
from htdata.read.metadata import DatasetMetadata, OutOfRange, collected_guard
from htdata.read.onerror import READ_ERRORS, SkipPolicy
from htdata.read.rawstream import RawMapRenderer, check_records
from htdata.read.samplerow import SampleRow, member_layout
from htdata.store import storage
from htdata.store.confine import inside

MAX_OPEN_SHARDS = 128   # an LRU of open shard files; one-episode units make many small shards
_SIZE_POS = tuple(INDEX_DTYPE.names.index(SIZE_FIELDS[s]) for s in MEMBER_ORDER)


def _from_meta(name: str):
    """A DatasetReader method that calls DatasetMetadata's method `name` (same arguments, same docstring)."""
    method = getattr(DatasetMetadata, name)

    @functools.wraps(method)
    def call(self, *args, **kwargs):
        return method(self.meta, *args, **kwargs)
    return call


def _meta_property(name: str) -> property:
    """A DatasetReader property that reads DatasetMetadata's attribute `name` (same docstring)."""
    held = getattr(DatasetMetadata, name, None)
    return property(lambda self: getattr(self.meta, name),
                    doc=held.__doc__ if isinstance(held, property) else f"`meta.{name}` (DatasetMetadata).")


class DatasetReader:
    """The samples of one committed version: random access, windows, streaming; `meta` holds its records.

    Args:
        root: the dataset root, a local path or an fsspec URL (file://, memory://, s3://...).
        validate_manifest: check the manifest against schemas/manifest.schema.json.
        version: the version to open (`htdata log` lists them); None: the current one.

    Raises:
        NoSuchVersion (an ArgumentError): `version` is not a committed version of the dataset.
        DatasetError: the version's records disagree with each other.
        RecordMismatch: a calibration record no longer matches its id or digest.
    """

    def __init__(self, root: str | os.PathLike, validate_manifest: bool = True, version: int | None = None):
        self.meta = DatasetMetadata(root, version=version, validate_manifest=validate_manifest)
        check_records(self)     # calibration ids and fit digests recomputed (htdata.read.rawstream)
        self._episode_ids = self.meta.episode_ids
        self._shard_names = self.meta.shard_names
        self._n = self.meta.num_samples
        self._handles: OrderedDict[int, object] = OrderedDict()
        self._pid = os.getpid()
        # a version that does not store its maps: decoded samples get them rendered from the raw rows
        self._renderer = None if MapStorage.of(self.manifest).stores_maps else RawMapRenderer(self)

    # -- the version's records: DatasetMetadata's, handed on ---------------
    root = _meta_property("root")
    manifest = _meta_property("manifest")
    stored = _meta_property("stored")
    version = _meta_property("version")
    episodes = _meta_property("episodes")
    index = _meta_property("index")
    region_map = _meta_property("region_map")
    place_map = _meta_property("place_map")
    episode_position = _from_meta("episode_position")
    episode_range = _from_meta("episode_range")
    locate = _from_meta("locate")
    coverage = _from_meta("coverage")
    layout = _from_meta("layout")
    split = _from_meta("split")
    episode_positions = _from_meta("episode_positions")
    sample_indices = _from_meta("sample_indices")

    # -- pickling / fork safety -------------------------------------------
    def __getstate__(self):
        state = self.__dict__.copy()
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
        """Close the shard files this process opened (a later read reopens them)."""
        if os.getpid() == self._pid:
            for handle in self._handles.values():
                handle.close()
        self._handles.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- index rows ----------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    def row(self, i: int) -> SampleRow:
        """Index row of a sample as plain ints.

        Args:
            i: global sample index (negative counts from the end).

        Raises:
            OutOfRange (an ArgumentError and IndexError): `i` outside the version's samples.
        """
        n = self._n
        if not -n <= i < n:
            raise OutOfRange(f"{self.root}: sample {i} out of range (dataset has {n})")
        values = self.meta.index[int(i) % n].item()   # one tuple: ~10x cheaper than field-by-field
        return SampleRow(values[0], values[1], values[2], values[3], tuple(values[p] for p in _SIZE_POS))

    def _key(self, row: SampleRow) -> str:
        return sample_key(self._episode_ids[row.episode], row.frame)

    def key(self, i: int) -> str:
        """The sample's key in its shard ("EPISODE__FRAME", 6 digits).

        Args:
            i: global sample index (negative counts from the end).
        """
        return self._key(self.row(i))

    # -- bytes -------------------------------------------------------------
    def _shard_path(self, shard: int, confined: bool = False) -> str:
        """shards/NAME of shard `shard`; `confined`: refused when it resolves outside the dataset (a symlink)."""
        if not 0 <= shard < len(self._shard_names):   # a damaged or hostile index row: one line, not IndexError
            raise DatasetError(f"{self.root}: an index row names shard {shard}, but version {self.version} has "
                               f"{len(self._shard_names)} shards (index.npy damaged?); run `htdata validate`")
        rel = f"{SHARDS_DIR}/{self._shard_names[shard]}"
        return inside(self.root, rel, f"shards[{shard}]") if confined else storage.join(self.root, rel)

    def _handle(self, shard: int):
        self._check_pid()
        handle = self._handles.get(shard)
        if handle is None:
            with collected_guard(self.root, self.version, self._shard_path(shard)):
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
            raise DatasetError(f"{self._shard_path(row.shard)}: truncated at sample {key} "
                               f"(wanted {size} B at {row.offset}, got {len(span)})")
        out = {}
        for suffix, rel, member_size in layout:
            header = span[rel:rel + BLOCK]
            expected = f"{key}.{suffix}"
            if not header_matches(header, expected.encode("utf-8"), member_size):
                raise DatasetError(f"{self._shard_path(row.shard)}: at offset {row.offset + rel} expected member "
                                   f"{expected} ({member_size} B), found {describe_header(header)}: "
                                   f"index and shard disagree")
            out[suffix] = span[rel + BLOCK:rel + BLOCK + member_size]
        return out

    def sample(self, i: int, suffixes=None) -> dict[str, bytes]:
        """Raw member bytes of a sample, keyed by suffix ("json", "rgb.jpg", ...).

        Args:
            i: global sample index (negative counts from the end).
            suffixes: the members wanted (absent ones are skipped; the read stops after the
                last one wanted); None: every member.

        Raises:
            OutOfRange (an ArgumentError and IndexError): `i` outside the version's samples.
            DatasetError: the shard is truncated there, or its tar headers disagree with the index.
        """
        return self.read_sample(i, suffixes)[2]

    def read_sample(self, i: int, suffixes=None) -> tuple[SampleRow, str, dict[str, bytes]]:
        """Index row, key and member bytes of a sample: one index lookup for callers needing all three.

        Args:
            i: global sample index (negative counts from the end).
            suffixes: the members wanted, as in `sample`; None: every member.

        Returns:
            (SampleRow, key, {suffix: bytes}).

        Raises:
            As `sample`.
        """
        row = self.row(i)
        key = self._key(row)
        return row, key, self._read_members(self._handle(row.shard), row, key, suffixes)

    def decode(self, members: dict[str, bytes], where: str = "sample") -> dict:
        """Decode raw members (format.decode_sample): rgb uint8 (224,224,3), tactile/bend per hand, meta.

        The maps are the stored ones: for a version that does not store them use `decoded(i)`.

        Args:
            members: {suffix: bytes}, as `sample` returns; "meta" is in the result only when
                the json member is (it always is in sample(i)).
            where: what an error names (e.g. the dataset and the sample's key).
        """
        return decode_sample(members, where)

    def decoded(self, i: int, suffixes=None) -> dict:
        """A sample decoded: rgb, tactile, bend, raw per hand, meta (docs/FORMAT.md "Reader / torch").

        A version whose maps are not stored (htdata/format/mapstorage.py) gets each map
        rendered from the raw rows (+ json) it reads for it.

        Args:
            i: global sample index (negative counts from the end).
            suffixes: the members to read and decode; None: every member.

        Raises:
            As `sample`.
        """
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
        if self._renderer is None:
            self._check_stored_maps(row, where, suffixes)
        out = decode_sample(asked, where)
        if self._renderer is not None:
            for hand in HANDS:
                if raw_member(hand) in members and (suffixes is None or tactile_member(hand) in suffixes):
                    out["tactile"][hand] = self._renderer.render(row.episode, hand, members, where)
        return out

    def _check_stored_maps(self, row: SampleRow, where: str, suffixes) -> None:
        """A version that records stored maps serves none from a sample holding raw rows but no map (a manifest
        claiming maps over shards written with maps = "raw"): a named error, as validate's hand_member FAIL,
        never a sample with its maps silently missing."""
        sizes = dict(zip(MEMBER_ORDER, row.sizes))
        for hand in HANDS:
            if suffixes is not None and tactile_member(hand) not in suffixes:
                continue
            if sizes.get(raw_member(hand), 0) and not sizes.get(tactile_member(hand), 0):
                raise DatasetError(f"{where}: holds {raw_member(hand)} but no {tactile_member(hand)} although the "
                                   f"version records stored maps: the manifest does not describe these shards "
                                   f"(`htdata validate` lists every such sample)")

    def window(self, episode: str | int, frame: int, k: int) -> list[dict]:
        """Decoded frames T-k..T (k+1 frames) of one episode; never crosses its start.

        Args:
            episode: an episode id or position.
            frame: T, the last frame of the window.
            k: how many frames before T (0: T alone).

        Raises:
            ArgumentError: k < 0.
            OutOfRange (an ArgumentError and IndexError): T is not a frame of the episode, or T - k < 0.
        """
        if k < 0:
            raise ArgumentError(f"window size k must be >= 0, got {k}")
        end = self.locate(episode, frame)
        if frame - k < 0:
            eid = self.episodes[self.episode_position(episode)]["episode_id"]
            raise OutOfRange(f"{self.root}: window of frames {frame - k}..{frame} would cross the start "
                             f"of episode {eid!r} (frame 0); need frame >= {k}")
        return [self.decoded(i) for i in range(end - k, end + 1)]

    def iter_samples(self, shards: list[int] | None = None, decode: bool = False,
                     suffixes=None, on_error: str = "raise") -> Iterator[tuple[int, dict]]:
        """Stream the samples shard by shard, each shard read front to back.

        Args:
            shards: shard numbers to read, in that order; None: every shard.
            decode: yield decoded samples (as `decoded`) instead of member bytes.
            suffixes: the members returned (and decoded), as in `sample`; None: every member.
            on_error: a sample that does not read or decode (htdata/read/onerror.py): "raise" (default),
                "warn" (skip it with one warning line naming it) or "skip"; a shard that does not open is
                skipped whole.

        Returns:
            An iterator of (global sample index, members or decoded sample).

        Raises:
            OutOfRange (an ArgumentError and IndexError): a shard number the version does not have.
            DatasetError: an index row or a tar header disagrees with the manifest (on_error="raise").
            VersionCollected: the version's shards were removed by `htdata gc` (whatever `on_error`).
        """
        policy = SkipPolicy(on_error)
        wanted = range(len(self._shard_names)) if shards is None else list(shards)
        bad = [s for s in wanted if not 0 <= s < len(self._shard_names)]
        if bad:
            raise OutOfRange(f"{self.root}: no shard {bad[0]} (version {self.version} has {len(self._shard_names)})")
        for shard in wanted:
            try:
                with collected_guard(self.root, self.version, self._shard_path(shard)):
                    f = storage.open_binary(self._shard_path(shard, confined=True))
            except READ_ERRORS as exc:
                if not policy.skips(exc, f"shard {self._shard_names[shard]} (every sample in it)"):
                    raise
                continue
            with f:
                yield from self._stream_shard(f, shard, decode, suffixes, policy)

    def _stream_shard(self, f, shard: int, decode: bool, suffixes, policy: SkipPolicy) -> Iterator[tuple[int, dict]]:
        """The samples of one open shard, front to back, as `iter_samples` yields them."""
        rows = self.meta.index
        entry = self.manifest["shards"][shard]
        first, count = int(entry["first_sample"]), int(entry["samples"])
        for i in range(first, first + count):
            try:
                values = rows[i].item()
                row = SampleRow(values[0], values[1], values[2], values[3], tuple(values[p] for p in _SIZE_POS))
                if row.shard != shard:
                    raise DatasetError(f"{self.root}: index row {i} names shard {row.shard}, "
                                       f"manifest puts it in {shard}")
                key = self._key(row)
                members = self._read_members(f, row, key, self._members_to_read(suffixes) if decode else suffixes)
                out = self._decode_row(row, members, f"{self.root}: {key}", suffixes) if decode else members
            except READ_ERRORS as exc:
                if not policy.skips(exc, f"sample {i} of shard {self._shard_names[shard]}"):
                    raise
                continue
            yield i, out


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
