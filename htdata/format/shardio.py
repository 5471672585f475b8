"""Atomic, deterministic USTAR tar shards with member offsets.

A shard is `shard-UUUUUU-KKK.tar` (UUUUUU = work unit, KKK = part within the
unit). It is written under `.shard-UUUUUU-KKK.tar.tmp`, fsynced, then linked
to its final name, which must not exist: a finished shard is never
overwritten and a crash leaves at most a temp file.

This module is the one place that writes AND parses tar headers
(`member_header`; `header_matches` for the reader's hot path, `parse_header`
for validation). Headers are written by hand (tarfile.TarInfo.tobuf, USTAR)
so we know every offset while writing and hash the bytes as they go out: with mtime 0,
uid/gid 0, mode 0o644 and empty owner names, equal input gives byte-identical
shards. USTAR fixes the layout: a 512-byte header, the data, zero padding to
512; the archive ends with two zero blocks. Standard readers (tar, tarfile,
webdataset) read the result unchanged.
"""

from __future__ import annotations

import hashlib
import os
import re
import tarfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from htdata.fileio import fsync_dir, link_exclusive
from htdata.format.table import MEMBER_ORDER

BLOCK = 512
MAX_NAME = 100  # USTAR name field; longer names would need the prefix field
MAX_PARTS_PER_UNIT = 1000
MAX_KEY_STEM = 64   # + "__" + frame (up to 8 digits) + "." + longest member suffix stays <= MAX_NAME
assert MAX_KEY_STEM + 2 + 8 + 1 + max(len(s) for s in MEMBER_ORDER) <= MAX_NAME
_USTAR_SIZE = slice(124, 136)   # size field: 11 octal digits + NUL
KEY_RE = re.compile(r"^[A-Za-z0-9_-]+__[0-9]{6,}$")


def shard_name(unit: int, part: int) -> str:
    if not 0 <= unit <= 999_999:
        raise ValueError(f"work unit {unit} outside 0..999999")
    if not 0 <= part < MAX_PARTS_PER_UNIT:
        raise ValueError(f"unit {unit}: shard part {part} outside 0..{MAX_PARTS_PER_UNIT - 1}")
    return f"shard-{unit:06d}-{part:03d}.tar"


def key_stem(episode_id: str) -> str:
    """The episode part of a sample key: the id itself, or a deterministic shortening of a long id.

    USTAR member names hold 100 bytes, so `{stem}__{frame}.{suffix}` must fit:
    ids longer than MAX_KEY_STEM keep their first characters plus a hash of
    the whole id (unique, stable, same on write and read). The full id stays
    in the sample JSON, episodes.jsonl and (by position) index.npy.
    """
    if len(episode_id) <= MAX_KEY_STEM:
        return episode_id
    digest = hashlib.sha256(episode_id.encode()).hexdigest()[:16]
    return f"{episode_id[:MAX_KEY_STEM - 17]}-{digest}"


def sample_key(episode_id: str, frame: int) -> str:
    """The sample key of docs/FORMAT.md: no dots (webdataset splits the key at the first dot)."""
    key = f"{key_stem(episode_id)}__{frame:06d}"
    if not KEY_RE.match(key):
        raise ValueError(f"invalid sample key {key!r}: episode ids are [A-Za-z0-9_-]+, frame >= 0")
    return key


def parse_key(key: str) -> tuple[str, int]:
    """Inverse of sample_key: (key stem, frame); the stem is the episode id unless it was shortened."""
    if not KEY_RE.match(key):
        raise ValueError(f"invalid sample key {key!r}")
    stem, frame = key.rsplit("__", 1)
    return stem, int(frame)


def padded(size: int) -> int:
    return (size + BLOCK - 1) // BLOCK * BLOCK


def member_offsets(first_header_offset: int, sizes: Iterable[int]) -> list[int]:
    """Data offsets of consecutive members whose first header is at `first_header_offset`.

    USTAR: data starts one block after its header; the next header follows the
    data padded to a whole block.
    """
    offsets = []
    header = int(first_header_offset)
    for size in sizes:
        offsets.append(header + BLOCK)
        header += BLOCK + padded(int(size))
    return offsets


def _tarfile_header(name: str, size: int) -> bytes:
    """tarfile's own USTAR header of a regular file (mtime 0, mode 644, root, no user names)."""
    info = tarfile.TarInfo(name)
    info.size = size
    info.mtime = 0
    info.mode = 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.type = tarfile.REGTYPE
    return info.tobuf(tarfile.USTAR_FORMAT, "utf-8", "strict")


# The header block of a sample member with the name and size fields blank: every other field is the
# same for all members. Filling in those two fields by hand gives tarfile's exact bytes (tests check
# that) at ~1/10th of tarfile's cost, which was ~5% of an ingest (8 members per sample).
_HEADER_TEMPLATE = bytearray(_tarfile_header("x", 0))
_HEADER_TEMPLATE[0:100] = bytes(100)
_HEADER_TEMPLATE[124:136] = bytes(12)
_HEADER_TEMPLATE[148:156] = b" " * 8          # checksum field counts as spaces while summing
_HEADER_SUM = sum(_HEADER_TEMPLATE)


def member_header(name: str, size: int) -> bytes:
    """A deterministic USTAR header block for a regular file (byte-identical to tarfile's)."""
    raw = name.encode("utf-8")
    if len(raw) > MAX_NAME:
        raise ValueError(f"tar member name longer than {MAX_NAME} bytes (USTAR): {name!r}")
    if not 0 <= size < 8 ** 11:       # what 11 octal digits hold; tarfile would refuse too
        return _tarfile_header(name, size)
    size_field = b"%011o\0" % size
    checksum = _HEADER_SUM + sum(raw) + sum(size_field)
    block = bytearray(_HEADER_TEMPLATE)
    block[0:len(raw)] = raw
    block[124:136] = size_field
    block[148:156] = b"%06o\0 " % checksum
    return bytes(block)


def parse_header(header: bytes) -> tuple[str, int]:
    """(name, size) of a tar header block; ValueError (tarfile.HeaderError) on a bad checksum."""
    info = tarfile.TarInfo.frombuf(header, "utf-8", "strict")
    return info.name, info.size


def header_matches(header: bytes, name: bytes, size: int) -> bool:
    """Cheap check for the read path: name field == name (NUL padded) and size field == size.

    Compares raw bytes in the encoding `member_header` writes; any other valid
    encoding of the same values falls back to tarfile's parser.
    """
    n = len(name)
    if (header[:n] == name and (n == MAX_NAME or header[n] == 0)
            and header[_USTAR_SIZE] == b"%011o\0" % size):
        return True
    try:
        info = tarfile.TarInfo.frombuf(header, "utf-8", "surrogateescape")
    except tarfile.HeaderError:
        return False
    return info.name.encode("utf-8", "surrogateescape") == name and info.size == size


def describe_header(header: bytes) -> str:
    """'name (size B)' of a header block, or why it is unreadable (for error messages)."""
    try:
        info = tarfile.TarInfo.frombuf(header, "utf-8", "surrogateescape")
    except tarfile.HeaderError as exc:
        return f"an unreadable header ({exc})"
    return f"{info.name} ({info.size} B)"


@dataclass
class ShardRecord:
    """A finished shard."""
    name: str
    sha256: str
    bytes: int
    samples: int


@dataclass
class SampleRecord:
    """Where one sample landed. `shard` is the shard's position within the unit."""
    key: str
    shard: int
    offset: int                       # byte offset of the first member's header
    sizes: dict[str, int] = field(default_factory=dict)  # member suffix -> bytes

    def to_dict(self) -> dict:
        """dataclasses.asdict's result, built directly (asdict deep-copies: ~1% of an ingest for every sample)."""
        return {"key": self.key, "shard": self.shard, "offset": self.offset, "sizes": dict(self.sizes)}


class _HashingFile:
    """Write-through file that hashes and counts the bytes written."""

    def __init__(self, path: Path):
        self.f = open(path, "xb")
        self.sha = hashlib.sha256()
        self.size = 0

    def write(self, data: bytes) -> None:
        self.f.write(data)
        self.sha.update(data)
        self.size += len(data)


class ShardWriter:
    """Write the samples of one work unit into `shard-UUUUUU-KKK.tar` files.

    Use as a context manager: on an exception the open shard's temp file is
    removed and finished shards stay. A sample is never split across shards.

    Args:
        directory: the dataset's shards/ folder (created if missing).
        unit: the work unit whose shards these are (names shard-UUUUUU-KKK.tar).
        samples_per_shard: samples per shard (>= 1).
        max_shard_bytes: also start a new shard before this size would be passed (None: no bound).
        fsync: fsync each finished shard and its folder (False only for throwaway output: benchmarks).

    Raises:
        ValueError: samples_per_shard < 1, max_shard_bytes below 4 tar blocks, or a unit out of range.
    """

    def __init__(self, directory: str | os.PathLike, unit: int, samples_per_shard: int,
                 max_shard_bytes: int | None = None, fsync: bool = True):
        if samples_per_shard < 1:
            raise ValueError(f"samples_per_shard must be >= 1, got {samples_per_shard}")
        if max_shard_bytes is not None and max_shard_bytes < BLOCK * 4:
            raise ValueError(f"max_shard_bytes too small: {max_shard_bytes}")
        shard_name(unit, 0)  # validates unit
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.unit = unit
        self.samples_per_shard = samples_per_shard
        self.max_shard_bytes = max_shard_bytes
        self.fsync = fsync
        self.shards: list[ShardRecord] = []
        self.samples: list[SampleRecord] = []
        self._out: _HashingFile | None = None
        self._count = 0
        self._closed = False
        self._last_key: str | None = None

    # -- paths -----------------------------------------------------------
    def _final_path(self, part: int) -> Path:
        return self.directory / shard_name(self.unit, part)

    def _temp_path(self, part: int) -> Path:
        return self.directory / ("." + shard_name(self.unit, part) + ".tmp")

    # -- writing ---------------------------------------------------------
    def _open_next(self) -> None:
        part = len(self.shards)
        final = self._final_path(part)
        if final.exists():
            raise FileExistsError(f"{final}: shard already exists; refusing to overwrite a finished shard")
        temp = self._temp_path(part)
        if temp.exists():  # left by a crashed run of this unit: never finished, safe to drop
            temp.unlink()
        self._out = _HashingFile(temp)
        self._count = 0

    def add_sample(self, key: str, members: dict[str, bytes]) -> SampleRecord:
        """Append one sample, finishing the open shard first when it is full.

        Args:
            key: the sample key (sample_key: `<episode>__<frame>`), never the previous sample's.
            members: suffix (table.MEMBER_ORDER: "json", "rgb.jpg", ...) -> non-empty bytes; "json" required.

        Returns:
            Where the sample went: its shard, offset and member sizes (also kept in `self.samples`).

        Raises:
            ValueError: the writer is closed, or a bad key, member name or member, or a repeated key.
            FileExistsError: the next shard's name exists already (a finished shard is never overwritten).
        """
        if self._closed:
            raise ValueError(f"unit {self.unit}: ShardWriter already closed")
        parse_key(key)
        unknown = set(members) - set(MEMBER_ORDER)
        if unknown:
            raise ValueError(f"{key}: unknown member(s) {sorted(unknown)}; allowed {MEMBER_ORDER}")
        if "json" not in members:
            raise ValueError(f"{key}: every sample needs a json member")
        if self._last_key is not None and key == self._last_key:
            raise ValueError(f"{key}: duplicate sample key")
        ordered = [(s, members[s]) for s in MEMBER_ORDER if s in members]
        for suffix, data in ordered:
            if not isinstance(data, (bytes, bytearray, memoryview)) or len(data) == 0:
                raise ValueError(f"{key}.{suffix}: member must be non-empty bytes")
        sample_bytes = sum(BLOCK + padded(len(d)) for _, d in ordered)
        if self._out is not None and (
            self._count >= self.samples_per_shard
            or (self.max_shard_bytes is not None and self._count > 0
                and self._out.size + sample_bytes + 2 * BLOCK > self.max_shard_bytes)
        ):
            self._finish_current()
        if self._out is None:
            self._open_next()
        out = self._out
        record = SampleRecord(key=key, shard=len(self.shards), offset=out.size,
                              sizes={s: len(d) for s, d in ordered})
        parts = []
        for suffix, data in ordered:
            parts.append(member_header(f"{key}.{suffix}", len(data)))
            parts.append(data)
            pad = padded(len(data)) - len(data)
            if pad:
                parts.append(bytes(pad))
        out.write(b"".join(parts))   # one write and one hash update per sample, not three per member
        self._count += 1
        self._last_key = key
        self.samples.append(record)
        return record

    def _finish_current(self) -> None:
        out = self._out
        part = len(self.shards)
        out.write(b"\0" * (2 * BLOCK))  # end-of-archive marker
        out.f.flush()
        if self.fsync:
            os.fsync(out.f.fileno())
        out.f.close()
        temp, final = self._temp_path(part), self._final_path(part)
        try:
            link_exclusive(temp, final)  # atomic and fails if `final` exists: no overwrite race
        except FileExistsError:
            raise FileExistsError(f"{final}: shard already exists; refusing to overwrite a finished shard") from None
        if self.fsync:
            fsync_dir(self.directory)
        self.shards.append(ShardRecord(name=final.name, sha256=out.sha.hexdigest(),
                                       bytes=out.size, samples=self._count))
        self._out = None

    def abort(self) -> None:
        """Drop the unfinished shard (temp file); finished shards stay."""
        if self._out is not None:
            self._out.f.close()
            self._temp_path(len(self.shards)).unlink(missing_ok=True)
            self._out = None
        self._closed = True

    def close(self) -> list[ShardRecord]:
        """Finish the open shard (linked to its final name); closing twice is harmless.

        Returns:
            Every shard record of the unit, in part order.

        Raises:
            FileExistsError: the open shard's final name exists already.
        """
        if not self._closed:
            if self._out is not None:
                self._finish_current()
            self._closed = True
        return self.shards

    def __enter__(self) -> "ShardWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

