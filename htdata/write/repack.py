"""Copy samples of committed shards into new shards, byte for byte (no re-encoding).

rm, trim and merge never rewrite a shard: the work units they touch are
re-packed into NEW units (fresh unit numbers, so fresh shard names) holding
only the samples kept, and the parent's shards stay as they are for the
versions that list them. A sample's members are copied as stored; only a
trimmed episode's json member is rewritten, because its key and frame index
are renumbered so frames stay 0..n-1, and `htdata renormalise` passes a
`rewrite` that re-encodes the maps of the episodes it recalibrates. A trimmed
episode's `taxels_sha256` (htdata/glove/calibration.py) is re-derived from the
kept samples' raw rows, so `validate --deep` still proves its maps.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from htdata.faults import crash_point
from htdata.format.codec import encode_json
from htdata.format.shardio import ShardWriter, sample_key
from htdata.format.table import JSON_MEMBER, SHARDS_DIR, raw_member
from htdata.glove.calibration import taxel_digest
from htdata.read.rawstream import RawMapRenderer, apply_paired
from htdata.read.reader import DatasetReader
from htdata.store.manifest import UnitResult
from htdata.store.parts import SHARD_NAME_RE, Part, part_from_unit, unit_of_shard


@dataclass
class KeptEpisode:
    """One episode to copy: its record (without computed fields) and the frames kept, in order.

    Args:
        record: the episode's record as the new version lists it.
        frames: source frame numbers within the episode; renumbered from 0 when not 0..n-1.
    """
    record: dict
    frames: range           # source frame numbers within the episode; renumbered from 0 when not 0..n-1

    @classmethod
    def whole(cls, record: dict) -> "KeptEpisode":
        """Every frame of the episode `record` describes (its `num_frames`).

        Args:
            record: the episode's record.

        Returns:
            KeptEpisode(record, range(num_frames)).
        """
        return cls(record, range(int(record["num_frames"])))


class SampleRewrite(Protocol):
    """Changes some episodes' members while re-packing (htdata.curate.renormalise.Recalibration)."""

    def members(self, episode_id: str, frame: int, members: dict[str, bytes]) -> dict[str, bytes]:
        """One sample's members as they go into the new shard.

        Args:
            episode_id: the sample's episode.
            frame: its frame number in the parent (before a trim renumbers it).
            members: suffix -> encoded bytes, as read (json already renumbered).

        Returns:
            The members to write (the same dict when this episode is not changed).
        """

    def record(self, record: dict) -> dict:
        """One episode's record as the new version lists it.

        Args:
            record: the episode record after the copy (num_frames, taxel digests set).

        Returns:
            The record to list.
        """


def clear_uncommitted(root: Path, next_unit: int) -> list[str]:
    """Delete shard files of units >= next_unit: an interrupted write left them, no version lists them.

    New units of this write then take the same numbers a run that never
    crashed would, so a re-run gives the same dataset. The caller holds the
    writer lock (no other writer can be making them right now).

    Args:
        root: the dataset root (local).
        next_unit: the parent's next free unit number (Snapshot.next_unit).

    Returns:
        The names of the files deleted.
    """
    return _clear_units(root, lambda unit: unit >= next_unit)


def clear_unit(root: Path, unit: int) -> list[str]:
    """Delete the shard files (temp ones too) of one unit no version lists: a unit is written whole, never
    on top of an earlier try's shards. The caller holds the writer lock.

    Args:
        root: the dataset root (local).
        unit: the unit about to be (re)written.

    Returns:
        The names of the files deleted.
    """
    return _clear_units(root, lambda u: u == unit)


def _clear_units(root: Path, doomed) -> list[str]:
    gone = []
    for p in sorted((Path(root) / SHARDS_DIR).glob("*shard-*.tar*")):
        name = p.name.lstrip(".").removesuffix(".tmp")
        if SHARD_NAME_RE.match(name) and doomed(unit_of_shard(name)):
            p.unlink()
            gone.append(p.name)
    return gone


def repack_unit(reader: DatasetReader, kept: list[KeptEpisode], unit: int, samples_per_shard: int,
                out_root: Path | None = None, rewrite: SampleRewrite | None = None) -> Part:
    """Write `kept` episodes' samples (read through `reader`) into unit `unit`'s shards.

    The shards go to the reader's dataset, or to `out_root`'s (merge writes B's samples into OUT).
    Members are copied as stored; a trimmed episode's json is renumbered and its taxel digests re-derived.

    Args:
        reader: the parent version the samples are read from.
        kept: the episodes to copy, each with the frames kept, in order.
        unit: the new unit number (its shards must not exist: clear_unit first).
        samples_per_shard: samples per new shard (samples_per_shard_of the part re-packed).
        out_root: the dataset the shards go to (None: the reader's).
        rewrite: changes members and records on the way (None: a byte-for-byte copy).

    Returns:
        The new Part: its shards, samples and episode records.

    Raises:
        ValueError: a kept frame outside its episode.
        FileExistsError: a shard of `unit` already exists (shardio.ShardWriter).
    """
    out_dir = Path(out_root if out_root is not None else reader.root) / SHARDS_DIR
    records = []
    with ShardWriter(out_dir, unit=unit, samples_per_shard=samples_per_shard) as writer:
        for ep in kept:
            eid = ep.record["episode_id"]
            first, n = reader.episode_range(eid)
            renumber = ep.frames != range(0, n)
            digests = TaxelRecount(reader, eid) if renumber and ep.record.get("taxels_sha256") else None
            for new_frame, frame in enumerate(ep.frames):
                if not 0 <= frame < n:
                    raise ValueError(f"episode {eid!r}: frame {frame} outside 0..{n - 1}")
                members = reader.sample(first + frame)
                key = sample_key(eid, new_frame)
                if renumber:
                    meta = json.loads(members[JSON_MEMBER])
                    meta.update({"key": key, "frame_index": new_frame})
                    members = {**members, JSON_MEMBER: encode_json(meta)}
                if renumber and digests is not None:
                    digests.add(members)
                if rewrite is not None:
                    members = rewrite.members(eid, frame, members)
                writer.add_sample(key, members)
                crash_point("repack_sample_written")
            record = {**ep.record, "num_frames": len(ep.frames)}
            if renumber and digests is not None:
                record = digests.finish(record)
            records.append(rewrite.record(record) if rewrite is not None else record)
    return part_from_unit(UnitResult(unit=unit, shards=writer.shards, samples=writer.samples, episodes=records))


class TaxelRecount:
    """The taxel digests of a trimmed episode's kept frames, from their raw rows under its calibration.

    Args:
        reader: the parent version (the episode's calibration and layouts).
        episode_id: the trimmed episode; its record has `taxels_sha256`.
    """

    def __init__(self, reader: DatasetReader, episode_id: str):
        self.renderer, self.pos = RawMapRenderer(reader), reader.episode_position(episode_id)
        self.where = f"episode {episode_id!r}"
        self.live: dict[str, list] = {h: [] for h in reader.episodes[self.pos]["taxels_sha256"]}

    def add(self, members: dict[str, bytes]) -> None:
        """Count one kept sample's taxels.

        Args:
            members: the sample's members (its raw rows, where stored).
        """
        for hand, blocks in self.live.items():
            if raw_member(hand) in members:
                normaliser, _ = self.renderer.parts_for(self.pos, hand)
                values, _ = apply_paired(normaliser, members, hand, self.where)
                blocks.append(values[:, normaliser.live_mask])

    def finish(self, record: dict) -> dict:
        """The record with the kept frames' digests (none where no raw rows are stored to derive them).

        Args:
            record: the episode record as copied.

        Returns:
            A new record whose `taxels_sha256` covers only the kept frames (left out when none were counted).
        """
        digests = {h: taxel_digest(b) for h, b in self.live.items() if b}
        record = {k: v for k, v in record.items() if k != "taxels_sha256"}
        return {**record, "taxels_sha256": digests} if digests else record


def samples_per_shard_of(part: Part) -> int:
    """Shard size to re-pack a part with: its largest shard's sample count (at least 1).

    Args:
        part: the parent's part being re-packed.

    Returns:
        The samples per shard for its new unit.
    """
    return max([1] + [int(s["samples"]) for s in part.shards])
