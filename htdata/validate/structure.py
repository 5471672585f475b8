"""Structure: manifest, episodes and index agree with each other and with the shards' tar headers.

Dataset level (`check_index`, `check_shard_files`, on the version loaded.py
reads and schema-checks): counts per shard and per
episode, unique keys, each episode contiguous with frames 0..n-1, the hands
each episode declares. Sample level, called by the shard workers
(`read_members`): the tar header at every index offset names `key.suffix`
with the indexed size (one 512-byte read per member); the sample JSON is
checked by samplejson.py.
"""

from __future__ import annotations

import numpy as np

from htdata.format.mapstorage import MapStorage
from htdata.format.shardio import BLOCK, member_offsets, parse_header, sample_key
from htdata.format.table import (
    HANDS,
    JSON_MEMBER,
    MEMBER_ORDER,
    RGB_MEMBER,
    SHARDS_DIR,
    SIZE_FIELDS,
    tactile_member,
)
from htdata.store.confine import PathOutsideDataset, inside
from htdata.store.manifest import load_manifest
from htdata.store.segments import version_shards
from htdata.store.versions import list_versions
from htdata.validate.loaded import Loaded
from htdata.validate.report import Check, Recorder


def group_rows(values: np.ndarray, n_groups: int) -> list[np.ndarray]:
    """Row positions holding each value 0..n_groups-1 (ascending): O(N log N), not one scan per group.

    Args:
        values: (N,) integer group of each row (e.g. the index's shard column).
        n_groups: how many groups (values lie in 0..n_groups-1).
    """
    order = np.argsort(values, kind="stable")
    bounds = np.searchsorted(values[order], np.arange(n_groups + 1))
    return [order[bounds[g]:bounds[g + 1]] for g in range(n_groups)]


# -- index.npy against the manifest and episode records ------------------------------------------

def check_index(ds: Loaded, check: Check) -> bool:
    """Counts, contiguity, order and key uniqueness from index.npy alone. False if rows are unusable."""
    _check_counts(ds, check)
    if not _rows_in_range(ds, check):
        return False
    _check_shard_rows(ds, check)
    _check_keys(ds, check)
    ep_rows = group_rows(ds.index["episode"], len(ds.episodes))
    for pos, ep in enumerate(ds.episodes):
        _check_episode_rows(ds, ep, ep_rows[pos], check)
    return True


def _check_counts(ds: Loaded, check: Check) -> None:
    m = ds.manifest
    check.checked["index_rows"] += len(ds.index)
    for what, expected, found in (("samples", m["counts"]["samples"], len(ds.index)),
                                  ("episodes", m["counts"]["episodes"], len(ds.episodes)),
                                  ("shards", m["counts"]["shards"], len(m["shards"]))):
        if expected != found:
            check.fail("count_" + what, f"manifest counts.{what} = {expected}, dataset holds {found}",
                       expected=expected, found=found)


def _rows_in_range(ds: Loaded, check: Check) -> bool:
    rows, n_shards, n_eps = ds.index, len(ds.manifest["shards"]), len(ds.episodes)
    if not len(rows) or (rows["shard"].max() < n_shards and rows["episode"].max() < n_eps):
        return True
    bad = np.flatnonzero((rows["shard"] >= n_shards) | (rows["episode"] >= n_eps))
    check.fail("index_range", f"{bad.size} index rows name a shard or episode that does not exist, "
               f"first at row {bad[0]}", sample=int(bad[0]),
               expected=f"shard < {n_shards}, episode < {n_eps}",
               found=f"shard {int(rows['shard'][bad[0]])}, episode {int(rows['episode'][bad[0]])}")
    return False


def _check_shard_rows(ds: Loaded, check: Check) -> None:
    """Samples per shard and first_sample as listed; shards in order; offsets increasing within a shard."""
    m, rows = ds.manifest, ds.index
    per_shard = np.bincount(rows["shard"], minlength=len(m["shards"]))
    first = 0
    for pos, entry in enumerate(m["shards"]):
        if per_shard[pos] != entry["samples"]:
            check.fail("shard_samples", f"shard {entry['name']}: manifest lists {entry['samples']} "
                       f"samples, index has {int(per_shard[pos])}", shard=entry["name"],
                       expected=entry["samples"], found=int(per_shard[pos]))
        if entry["first_sample"] != first:
            check.fail("shard_first_sample", f"shard {entry['name']}: first_sample", shard=entry["name"],
                       expected=first, found=entry["first_sample"])
        first += int(per_shard[pos])
    if len(rows) and np.any(np.diff(rows["shard"].astype(np.int64)) < 0):
        bad = int(np.flatnonzero(np.diff(rows["shard"].astype(np.int64)) < 0)[0]) + 1
        check.fail("index_order", f"index row {bad} goes back to an earlier shard", sample=bad)
    same_shard = rows["shard"][1:] == rows["shard"][:-1]
    back = np.flatnonzero(same_shard & (rows["offset"][1:] <= rows["offset"][:-1])) + 1
    for r in back[:check.max_listed]:
        check.fail("offset_order", f"index row {r}: offset does not increase within its shard",
                   sample=int(r), shard=m["shards"][int(rows["shard"][r])]["name"],
                   expected=f"> {int(rows['offset'][r - 1])}", found=int(rows["offset"][r]))


def _check_keys(ds: Loaded, check: Check) -> None:
    rows = ds.index
    keys = rows["episode"].astype(np.int64) * (1 << 32) + rows["frame"].astype(np.int64)
    uniq, counts = np.unique(keys, return_counts=True)
    for k in uniq[counts > 1][:check.max_listed]:
        eid, frame = ds.episodes[int(k >> 32)]["episode_id"], int(k & 0xFFFFFFFF)
        key = sample_key(eid, frame)
        check.fail("key_duplicate", f"sample key {key} appears {int(counts[uniq == k][0])} times",
                   key=key, episode=eid, frame=frame)
    check.checked["keys"] += int(uniq.size)


def _check_episode_rows(ds: Loaded, ep: dict, pos_rows: np.ndarray, check: Check) -> None:
    """One episode: num_frames, contiguous rows from first_sample, frames 0..n-1, shards list, hands."""
    rows, eid, count = ds.index, ep["episode_id"], int(pos_rows.size)
    where = {"episode": eid}
    if count != ep["num_frames"]:
        check.fail("episode_samples", f"episode {eid}: num_frames {ep['num_frames']} but the index "
                   f"holds {count} samples", **where, expected=ep["num_frames"], found=count)
    if count == 0:
        return
    if pos_rows[-1] - pos_rows[0] + 1 != count:
        gap = int(pos_rows[np.flatnonzero(np.diff(pos_rows) != 1)[0] + 1])
        check.fail("episode_not_contiguous", f"episode {eid}: its samples are not contiguous in the "
                   f"index (interrupted before row {gap})", **where, sample=gap)
    if int(pos_rows[0]) != ep["first_sample"]:
        check.fail("episode_first_sample", f"episode {eid}: first_sample", **where,
                   expected=ep["first_sample"], found=int(pos_rows[0]))
    frames = rows["frame"][pos_rows].astype(np.int64)
    wrong = np.flatnonzero(frames != np.arange(count))
    if wrong.size:
        r = int(wrong[0])
        check.fail("frame_order", f"episode {eid}: frames not 0..{count - 1} in order; index row "
                   f"{int(pos_rows[r])} holds frame {int(frames[r])}", **where,
                   sample=int(pos_rows[r]), frame=int(frames[r]), expected=r, found=int(frames[r]))
    shards = ds.manifest["shards"]
    shard_names = sorted({shards[s]["name"] for s in np.unique(rows["shard"][pos_rows])})
    if sorted(ep["shards"]) != shard_names:
        check.fail("episode_shards", f"episode {eid}: shards list disagrees with the index", **where,
                   expected=shard_names, found=sorted(ep["shards"]))
    # RGB-only samples (format 3: RGB frames kept without tactile) hold no map member of any hand (its raw
    # rows when the version does not store maps: htdata/format/mapstorage.py)
    storage = MapStorage.of(ds.manifest)
    no_tactile = np.all([rows[SIZE_FIELDS[storage.map_member(h)]][pos_rows] == 0 for h in HANDS], axis=0)
    rgb_only = no_tactile & (rows[SIZE_FIELDS[RGB_MEMBER]][pos_rows] > 0)
    declared = sum((ep.get("rgb_only_frames") or {}).values())
    if int(rgb_only.sum()) != declared:
        check.fail("rgb_only_count", f"episode {eid}: {int(rgb_only.sum())} index rows hold RGB without tactile, "
                   f"the record declares {declared} RGB-only frames", **where,
                   expected=declared, found=int(rgb_only.sum()))
    for hand in HANDS:
        member = storage.map_member(hand)
        col = rows[SIZE_FIELDS[member]][pos_rows]
        has = hand in ep["hands"]
        unstored = rows[SIZE_FIELDS[tactile_member(hand)]][pos_rows] if not storage.stores_maps else col[:0]
        if unstored.any():
            r = int(pos_rows[np.flatnonzero(unstored)[0]])
            check.fail("hand_member", f"episode {eid}: index row {r} has a {tactile_member(hand)}, but the version "
                       f"records maps = \"raw\" (no map members)", **where, sample=r, frame=int(rows['frame'][r]))
        if has and not ((col > 0) | rgb_only).all():
            r = int(pos_rows[np.flatnonzero((col == 0) & ~rgb_only)[0]])
            check.fail("hand_member", f"episode {eid} has a {hand} hand but index row {r} has no "
                       f"{member}", **where, sample=r, frame=int(rows['frame'][r]))
        if not has and (col > 0).any():
            r = int(pos_rows[np.flatnonzero(col > 0)[0]])
            check.fail("hand_member", f"episode {eid} has no {hand} hand but index row {r} has a "
                       f"{member}", **where, sample=r, frame=int(rows['frame'][r]))


def check_shard_files(ds: Loaded, check: Check) -> None:
    """Files in shards/ no version lists (a temp file left by a crash only warns).

    In a versioned dataset, shards of other committed versions are expected,
    and one no version lists (an interrupted write's) only warns: the next
    write or `htdata gc` removes it. Unversioned: every unlisted shard fails.
    """
    versioned = "version" in ds.manifest
    listed = {s["name"] for s in ds.manifest["shards"]}
    if versioned:
        for v in list_versions(ds.root):
            try:
                listed |= {s["name"] for s in version_shards(ds.root, load_manifest(ds.root, validate=False, version=v))}
            except (OSError, ValueError) as exc:
                check.warn("version_unreadable", f"version {v}: {exc}", version=v)
    for entry in ds.manifest["shards"]:
        try:
            inside(ds.root, f"{SHARDS_DIR}/{entry['name']}", "shard")
        except PathOutsideDataset as exc:
            check.fail("path_outside", str(exc), shard=entry["name"])
    shard_dir = ds.root / SHARDS_DIR
    present = sorted(p.name for p in shard_dir.iterdir()) if shard_dir.is_dir() else []
    for name in present:
        if name.endswith(".tar") and name not in listed:
            if versioned:
                check.warn("shard_unlisted", f"{SHARDS_DIR}/{name} is listed by no version (left by an "
                           f"interrupted write; htdata gc removes it)", shard=name)
            else:
                check.fail("shard_extra", f"{SHARDS_DIR}/{name} is not listed in the manifest", shard=name)
        elif name.endswith(".tmp"):
            check.warn("shard_temp", f"{SHARDS_DIR}/{name}: temp file left by an interrupted write",
                       shard=name)


# -- one sample, inside a shard worker -----------------------------------------------------------

def read_members(f, shard: str, key: str, row, where: dict, need_bytes: bool,
                 rec: Recorder) -> dict[str, bytes] | None:
    """Check the tar header at each indexed member offset of one sample in the open shard `f`.

    Returns the member bytes read (the JSON always, every member when
    `need_bytes`), or None after the first bad member (recorded in `rec`).
    """
    present = [s for s in MEMBER_ORDER if int(row[SIZE_FIELDS[s]]) > 0]
    sizes = [int(row[SIZE_FIELDS[s]]) for s in present]
    members: dict[str, bytes] = {}
    for suffix, size_expected, data_off in zip(present, sizes, member_offsets(int(row["offset"]), sizes)):
        rec.checked["members"] += 1
        header_off = data_off - BLOCK
        f.seek(header_off)
        header = f.read(BLOCK)
        expected_name = f"{key}.{suffix}"
        if len(header) < BLOCK:
            rec.fail("member_truncated", f"{shard}: header of {expected_name} at offset {header_off} "
                     f"lies past the end of the shard", **where, expected=expected_name,
                     found=f"{len(header)} bytes")
            return None
        try:
            name, tar_size = parse_header(header)
        except Exception as exc:  # tarfile raises its own HeaderError family (and UnicodeDecodeError)
            rec.fail("member_header", f"{shard}: no valid tar header at offset {header_off} for "
                     f"{expected_name}: {exc}", **where, expected=expected_name, found="invalid header")
            return None
        if name != expected_name or tar_size != size_expected:
            rec.fail("member_offset", f"{shard}: index offset {header_off} points at {name!r} "
                     f"({tar_size} bytes)", **where, expected=f"{expected_name} ({size_expected} bytes)",
                     found=f"{name} ({tar_size} bytes)")
            return None
        if suffix == JSON_MEMBER or need_bytes:
            data = f.read(size_expected)
            if len(data) != size_expected:
                rec.fail("member_truncated", f"{shard}: {expected_name} is cut short", **where,
                         expected=size_expected, found=len(data))
                return None
            members[suffix] = data
    return members
