"""The per-shard worker: structure (and, when asked, content) of every sample of one shard.

The parent cuts the work into one picklable `ShardJob` per shard
(`shard_jobs`); `check_shard` runs in a worker process (`run_jobs`: a
process pool when workers > 1) and returns plain data the parent merges:
{"structure", "content": Recorder dicts, "timestamps": columns for the
shard's rows (+ "row": their global positions), "hashes": [(row,
frame_digest)], "sensor": sensor accumulator}.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from htdata.format.mapstorage import MapStorage
from htdata.format.shardio import sample_key
from htdata.format.table import HANDS, JSON_MEMBER, SHARDS_DIR, tactile_member
from htdata.store.confine import PathOutsideDataset, inside
from htdata.store.fsutil import sha256_file
from htdata.validate.content import check_content
from htdata.validate.geometry import coverage_geometries
from htdata.validate.loaded import Loaded
from htdata.validate.report import Recorder
from htdata.validate.samplejson import check_sample_json
from htdata.validate.sensors import hand_key
from htdata.validate.splits import frame_digest
from htdata.validate.structure import group_rows, read_members
from htdata.validate.timestamps import empty_timestamps, record_timestamps


@dataclass
class ShardJob:
    """Everything one worker needs to check one shard (picklable, no open files)."""
    shard_pos: int
    name: str
    path: str
    sha256: str
    bytes: int
    rows: np.ndarray                       # index rows of this shard (INDEX_DTYPE)
    row_ids: np.ndarray                    # their global positions
    episode_ids: list[str]                 # per row
    decode: np.ndarray                     # per row: decode the content
    content_hash: bool                     # hash rgb+tactile bytes (split leakage check)
    coverage: dict[str, np.ndarray] = field(default_factory=dict)   # hand_key -> (224,224) bool
    region_map: np.ndarray | None = None
    tactile_pixel_type: str = "half"       # manifest codec.tactile.pixel_type
    map_members: dict[str, str] | None = None   # hand -> member carrying its map (MapStorage.map_member)


def outside(root, name: str) -> bool:
    """True when shards/NAME resolves outside the dataset root (a symlink to elsewhere)."""
    try:
        inside(root, f"{SHARDS_DIR}/{name}", "shard")
    except PathOutsideDataset:
        return True
    return False


def shard_jobs(ds: Loaded, decode: np.ndarray, coverage: dict[str, np.ndarray], region_map: np.ndarray | None,
               content_hash: bool) -> list[ShardJob]:
    """One job per manifest shard, each carrying only the coverage maps of its episodes."""
    eids = [ep["episode_id"] for ep in ds.episodes]
    cov_by_hand = {}
    for ep in ds.episodes:
        for hand, layout_id in ep["layouts"].items():
            if layout_id in coverage:
                cov_by_hand[hand_key(ep["episode_id"], hand)] = coverage[layout_id]
    jobs = []
    rows = ds.index
    map_members = {h: MapStorage.of(ds.manifest).map_member(h) for h in HANDS}
    shard_rows_of = group_rows(rows["shard"], len(ds.manifest["shards"]))
    for pos, entry in enumerate(ds.manifest["shards"]):
        if outside(ds.root, entry["name"]):
            continue   # check_shard_files failed it (path_outside): a file outside the dataset is never read
        ids = shard_rows_of[pos]
        shard_rows = np.asarray(rows[ids])
        ep_ids = [eids[int(e)] for e in shard_rows["episode"]]
        needed = {hand_key(e, h) for e in set(ep_ids) for h in HANDS}
        jobs.append(ShardJob(
            shard_pos=pos, name=entry["name"], path=str(ds.root / SHARDS_DIR / entry["name"]),
            sha256=entry["sha256"], bytes=entry["bytes"], rows=shard_rows, row_ids=ids,
            episode_ids=ep_ids, decode=decode[ids], content_hash=content_hash,
            coverage={k: v for k, v in cov_by_hand.items() if k in needed}, region_map=region_map,
            tactile_pixel_type=ds.manifest["codec"]["tactile"].get("pixel_type", "half"),
            map_members=map_members))
    return jobs


def run_jobs(jobs: list[ShardJob], workers: int) -> list[dict]:
    if workers <= 1 or len(jobs) <= 1:
        return [check_shard(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(check_shard, jobs))


def check_shard(job: ShardJob) -> dict:
    """Structure (+ content when asked) of one shard. Returns plain data for the parent."""
    state = _ShardCheck(job)
    if state.check_file():
        with open(job.path, "rb") as f:
            for i in range(len(job.rows)):
                state.check_sample(f, i)
    return state.result()


class _ShardCheck:
    """What a worker gathers while it reads one shard."""

    def __init__(self, job: ShardJob):
        self.job = job
        self.structure, self.content = Recorder(), Recorder()
        self.geometry = coverage_geometries(job.coverage, job.region_map)
        self.timestamps = {"row": job.row_ids.copy(), **empty_timestamps(len(job.rows))}
        self.hashes: list[tuple[int, str]] = []
        self.sensor: dict = {}

    def result(self) -> dict:
        return {"structure": self.structure.to_dict(), "content": self.content.to_dict(),
                "timestamps": self.timestamps, "hashes": self.hashes, "sensor": self.sensor}

    def check_file(self) -> bool:
        """The shard file exists with the manifest's size and sha256. False when it is missing."""
        job, base = self.job, {"shard": self.job.name}
        if not os.path.isfile(job.path):
            self.structure.fail("shard_missing", f"shard {job.name} listed in the manifest is missing "
                                f"({len(job.rows)} samples lost)", **base, expected=f"{job.bytes} bytes",
                                found="no file")
            return False
        size = os.path.getsize(job.path)
        self.structure.checked["shards"] += 1
        if size != job.bytes:
            self.structure.fail("shard_size", f"shard {job.name} has {size} bytes, manifest says {job.bytes}"
                                + (" (truncated)" if size < job.bytes else ""), **base,
                                expected=job.bytes, found=size)
        digest = sha256_file(job.path)
        if digest != job.sha256:
            self.structure.fail("shard_sha256", f"shard {job.name}: sha256 differs from the manifest "
                                f"(content changed or corrupted)", **base, expected=job.sha256, found=digest)
        return True

    def check_sample(self, f, i: int) -> None:
        """Row i of the shard: member headers, sample JSON, timestamps, frame hash, content."""
        job = self.job
        row, eid = job.rows[i], job.episode_ids[i]
        frame = int(row["frame"])
        key = sample_key(eid, frame)
        where = {"shard": job.name, "key": key, "episode": eid, "frame": frame, "sample": int(job.row_ids[i])}
        need_bytes = bool(job.decode[i]) or job.content_hash
        members = read_members(f, job.name, key, row, where, need_bytes, self.structure)
        self.structure.checked["samples"] += 1
        if members is None:
            return
        if JSON_MEMBER not in members:
            self.structure.fail("sample_json", f"{key}: no {JSON_MEMBER} member in the index", **where)
            return
        meta = check_sample_json(self.structure, members[JSON_MEMBER], key, eid, frame, row, where,
                                 self.job.map_members)
        if meta is None:
            return
        record_timestamps(self.timestamps, i, meta)
        if job.content_hash:
            self.hashes.append((int(job.row_ids[i]), frame_digest(members)))
        if job.decode[i]:
            hands_present = [h for h in HANDS if tactile_member(h) in members]
            check_content(self.geometry, self.content, key, where, members, hands_present, self.sensor,
                          self.job.tactile_pixel_type)
