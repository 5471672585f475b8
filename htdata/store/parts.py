"""A dataset as parts, and the assembly of parts into one version's index.

A part is one work unit's output as arrays: its shards (manifest entries),
its index rows (`shard` and `episode` columns LOCAL to the part) and its
episode records. An ingest unit makes its rows where it ran
(`part_from_unit`, a loop over its samples in the worker) and the commit
takes them back as arrays (`part_from_rows`, checked vectorised: the
driver never loops over samples); every later write (append, rm, trim, merge) reuses the
parts of the parent version it does not touch (`parts_of_version`, numpy
slices of the parent's index: no Python object per sample, so a write costs
O(what it changes) + O(index) vectorised) and `assemble` concatenates
parts into the global rows, shard list and episode records of the new
version. Global order = parts in the order given, shards in part order,
samples in shard order; an episode lives in exactly one part, its frames
contiguous 0..n-1.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from htdata.errors import DatasetError
from htdata.format.shardio import key_stem, parse_key
from htdata.format.table import INDEX_DTYPE, SIZE_FIELDS

SHARD_NAME_RE = re.compile(r"^shard-(\d{6})-(\d{3})\.tar$")
# Episode record fields `assemble` computes; a part's records come without them.
COMPUTED_FIELDS = ("first_sample", "shards")


@dataclass
class Part:
    unit: int
    shards: list[dict]            # manifest shard entries: name, sha256, bytes, samples
    rows: np.ndarray              # INDEX_DTYPE; shard/episode columns index this part's lists
    episodes: list[dict]          # records (num_frames set), without first_sample / shards
    # the records were schema-checked where they were made (an ingest unit, in its worker): the commit
    # need not check them again, so the driver's commit costs no schema check per new episode
    records_checked: bool = False

    @property
    def episode_ids(self) -> list[str]:
        return [e["episode_id"] for e in self.episodes]


@dataclass
class Assembled:
    rows: np.ndarray              # INDEX_DTYPE, global
    episodes: list[dict]          # records with first_sample, shards, num_frames
    shards: list[dict]            # manifest entries with first_sample
    unchecked: list[bool]         # per episode: its record still needs the schema check (Part.records_checked)


def unit_of_shard(name: str) -> int:
    m = SHARD_NAME_RE.match(name)
    if not m:
        raise DatasetError(f"shard name {name!r} is not shard-UUUUUU-KKK.tar")
    return int(m.group(1))


def part_from_unit(unit) -> Part:
    """Check one unit's records (htdata.store.manifest.UnitResult) and turn them into a Part.

    Errors name the unit and the sample: episodes without samples, samples
    without an episode, frames not contiguous from 0, unknown shards.
    """
    where = f"unit {unit.unit}"
    records = {}
    for rec in unit.episodes:
        if rec["episode_id"] in records:
            raise DatasetError(f"{where}: episode {rec['episode_id']!r} appears twice in the dataset")
        records[rec["episode_id"]] = {k: v for k, v in rec.items() if k not in COMPUTED_FIELDS}
    rows = np.zeros(len(unit.samples), dtype=INDEX_DTYPE)
    order: list[str] = []
    current, expected = None, 0
    by_stem = {key_stem(e): e for e in records}
    for i, sample in enumerate(unit.samples):
        stem, frame = parse_key(sample.key)
        eid = by_stem.get(stem)
        if eid is None:
            raise DatasetError(f"{where}: sample {sample.key} has no episode record")
        if eid != current:
            if eid in order:
                raise DatasetError(f"{where}: frames of episode {eid!r} are not contiguous (at {sample.key})")
            order.append(eid)
            current, expected = eid, 0
        if frame != expected:
            raise DatasetError(f"{where}: episode {eid!r}: expected frame {expected}, got {sample.key}")
        expected += 1
        if not 0 <= sample.shard < len(unit.shards):
            raise DatasetError(f"{where}: sample {sample.key} names shard {sample.shard} of {len(unit.shards)}")
        row = rows[i]
        row["shard"], row["offset"], row["episode"], row["frame"] = sample.shard, sample.offset, len(order) - 1, frame
        for suffix, size in sample.sizes.items():
            row[SIZE_FIELDS[suffix]] = size
    missing = set(records) - set(order)
    if missing:
        raise DatasetError(f"{where}: episode record(s) without samples: {sorted(missing)}")
    shards = [{"name": s.name, "sha256": s.sha256, "bytes": int(s.bytes), "samples": int(s.samples)}
              for s in unit.shards]
    episodes = [records[e] for e in order]
    _set_num_frames(episodes, rows, where)
    return Part(unit=int(unit.unit), shards=shards, rows=rows, episodes=episodes)


def part_from_rows(unit: int, shards: list[dict], rows: np.ndarray, episodes: list[dict],
                   records_checked: bool = False) -> Part:
    """A Part from a unit's own index rows (made by `part_from_unit` where the unit ran), checked with
    whole-array operations: no Python per sample, so a commit costs O(units) + vectorised O(samples).

    The rows must name the unit's shards and episodes by position, episodes in order and contiguous,
    frames 0..n-1 within each, shards in order with byte offsets rising inside each. Errors name the unit.
    """
    where = f"unit {unit}"
    if rows.dtype != INDEX_DTYPE:
        raise DatasetError(f"{where}: index rows have dtype {rows.dtype}, not {INDEX_DTYPE}")
    n = len(rows)
    records = [{k: v for k, v in rec.items() if k not in COMPUTED_FIELDS} for rec in episodes]
    if n == 0 and records:
        raise DatasetError(f"{where}: episode record(s) without samples: {[e['episode_id'] for e in records]}")
    if n:
        ep, shard = rows["episode"].astype(np.int64), rows["shard"].astype(np.int64)
        step, shard_step = np.diff(ep), np.diff(shard)
        if ep[0] != 0 or ep[-1] != len(records) - 1 or np.any((step != 0) & (step != 1)):
            raise DatasetError(f"{where}: index rows do not hold the unit's {len(records)} episode(s) in order, "
                               f"each contiguous (episode column {ep[0]}..{ep[-1]})")
        if shard[0] != 0 or shard[-1] != len(shards) - 1 or np.any((shard_step != 0) & (shard_step != 1)):
            raise DatasetError(f"{where}: index rows do not fill the unit's {len(shards)} shard(s) in order")
        starts = np.flatnonzero(np.r_[True, step != 0])
        expected = np.arange(n) - np.repeat(starts, np.diff(np.r_[starts, n]))
        bad = np.flatnonzero(rows["frame"].astype(np.int64) != expected)
        if bad.size:
            i = int(bad[0])
            raise DatasetError(f"{where}: episode {records[int(ep[i])]['episode_id']!r}: expected frame "
                               f"{int(expected[i])}, got {int(rows['frame'][i])}")
        offsets = rows["offset"].astype(np.int64)
        if np.any((shard_step == 0) & (np.diff(offsets) <= 0)):
            raise DatasetError(f"{where}: sample offsets do not rise inside a shard")
    _set_num_frames(records, rows, where)
    return Part(unit=int(unit), rows=np.array(rows, dtype=INDEX_DTYPE), episodes=records,
                shards=[{k: s[k] for k in ("name", "sha256", "bytes", "samples")} for s in shards],
                records_checked=records_checked)


def _set_num_frames(episodes: list[dict], rows: np.ndarray, where: str) -> None:
    counts = np.bincount(rows["episode"], minlength=len(episodes)) if len(rows) else np.zeros(len(episodes), int)
    for pos, ep in enumerate(episodes):
        count = int(counts[pos])
        if "num_frames" in ep and ep["num_frames"] != count:
            raise DatasetError(f"{where}: episode {ep['episode_id']!r}: record says num_frames={ep['num_frames']}, "
                               f"shards hold {count} samples")
        ep["num_frames"] = count


def parts_of_version(manifest: dict, episodes: list[dict], index: np.ndarray) -> list[Part]:
    """The parts of a committed version (shards grouped by their unit number), in index order."""
    shards = manifest["shards"]
    units = [unit_of_shard(s["name"]) for s in shards]
    parts: list[Part] = []
    start = 0
    while start < len(shards):
        stop = start
        while stop < len(shards) and units[stop] == units[start]:
            stop += 1
        first = int(shards[start]["first_sample"])
        n = sum(int(s["samples"]) for s in shards[start:stop])
        rows = np.array(index[first:first + n])          # a copy: the parent's mmap stays untouched
        eps = np.unique(rows["episode"]) if n else np.zeros(0, np.int64)
        rows["shard"] -= start
        rows["episode"] = np.searchsorted(eps, rows["episode"])
        records = [{k: v for k, v in episodes[int(e)].items() if k not in COMPUTED_FIELDS} for e in eps]
        parts.append(Part(unit=units[start], rows=rows, episodes=records,
                          shards=[{k: s[k] for k in ("name", "sha256", "bytes", "samples")}
                                  for s in shards[start:stop]]))
        start = stop
    if len({p.unit for p in parts}) != len(parts):
        raise DatasetError("shards of one work unit are not contiguous in the manifest")
    return parts


def assemble(parts: list[Part]) -> Assembled:
    """Concatenate parts into one version's global rows, shard entries and episode records."""
    seen: dict[str, int] = {}
    for p in parts:
        for eid in p.episode_ids:
            if eid in seen:
                raise DatasetError(f"unit {p.unit}: episode {eid!r} appears twice in the dataset "
                                   f"(also in unit {seen[eid]})")
            seen[eid] = p.unit
    names = [s["name"] for p in parts for s in p.shards]
    if len(set(names)) != len(names):
        raise DatasetError("a shard is listed twice: " + ", ".join(sorted({n for n in names if names.count(n) > 1})))
    rows = np.concatenate([p.rows for p in parts]) if parts else np.zeros(0, INDEX_DTYPE)
    shard_base = np.cumsum([0] + [len(p.shards) for p in parts])
    ep_base = np.cumsum([0] + [len(p.episodes) for p in parts])
    lengths = [len(p.rows) for p in parts]
    if parts:
        rows["shard"] += np.repeat(shard_base[:-1], lengths).astype(rows["shard"].dtype)
        rows["episode"] += np.repeat(ep_base[:-1], lengths).astype(rows["episode"].dtype)
    shards = [dict(s) for p in parts for s in p.shards]
    episodes = [dict(e) for p in parts for e in p.episodes]
    _fill_positions(rows, shards, episodes)
    return Assembled(rows=rows, episodes=episodes, shards=shards,
                     unchecked=[not p.records_checked for p in parts for _ in p.episodes])


def _fill_positions(rows: np.ndarray, shards: list[dict], episodes: list[dict]) -> None:
    """first_sample of shards and episodes, each episode's shard names; checks counts agree."""
    counts = np.bincount(rows["shard"], minlength=len(shards)) if len(rows) else np.zeros(len(shards), int)
    first = 0
    for pos, entry in enumerate(shards):
        if counts[pos] != entry["samples"]:
            raise DatasetError(f"shard {entry['name']}: records {entry['samples']} samples, index has {counts[pos]}")
        entry["first_sample"] = first
        first += entry["samples"]
    _set_num_frames(episodes, rows, "assemble")
    starts = np.searchsorted(rows["episode"], np.arange(len(episodes))) if len(rows) else np.zeros(len(episodes))
    pairs = np.unique(np.stack([rows["episode"].astype(np.int64), rows["shard"].astype(np.int64)], 1), axis=0) \
        if len(rows) else np.zeros((0, 2), np.int64)
    by_episode: dict[int, list[str]] = {}
    for e, s in pairs.tolist():
        by_episode.setdefault(e, []).append(shards[s]["name"])
    for pos, ep in enumerate(episodes):
        ep["first_sample"] = int(starts[pos])
        ep["shards"] = by_episode.get(pos, [])
