"""`htdata validate`: prove a committed dataset is sound.

Checks (each a named section of the report, with counts and every failure
pinpointed by shard / sample key / episode / frame / expected / found):

- structure: dataset.json, episodes.jsonl and every sample JSON valid against
  schemas/; episodes.jsonl and index.npy sha256; every listed shard present
  with its sha256 and size, no extra shard; sample counts per shard and per
  episode; unique keys; each episode's frames contiguous and ordered 0..n-1;
  the tar header at every index offset names `key.suffix` with the indexed
  size (one 512-byte read per member: cheap for all samples).
- content: decodes every sample (`--deep`) or a seeded sample (`--sample-frac`,
  plus the first frame of every episode): RGB (224,224,3) uint8; tactile EXR
  half (224,224), finite, in [0,1], zero outside the layout's coverage; bend
  vectors 1-D finite.
- time: RGB timestamps strictly increasing per episode; tactile timestamps
  never decrease (a repeated tactile timestamp means one glove frame was
  paired with two RGB frames, which nearest-neighbour sync allows when the
  glove is slower than the camera: counted as a warning); gaps (> 1.5
  periods) and fps deviation (> 5%) warn; |t_rgb - t_tactile| above the
  sync tolerance (episode sync report `max_skew_ns`, else the source
  pipeline's `sync.max_skew_ms`) fails.
- sensors (warnings only): regions (canonical region map within coverage)
  whose mean never changes over an episode's decoded frames (dead if always
  0, stuck otherwise), saturated fraction (>= 0.999), all-zero hands.
- splits (`--split NAME`): the split's manifest hash; OOD tasks absent from
  train and test; parts disjoint and covering every episode; no
  byte-identical frame (sha256 of rgb + tactile member bytes) in two parts;
  stated counts and ratios equal to what the parts hold.
- stats: frames per task / scene / hand; contact-area and pressure histograms.

Shards are checked by workers (one task per shard, a process pool when
workers > 1): the main process only merges small per-shard results.
Exit status 0 when every check passes (warnings allowed), 1 otherwise.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
import time
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path

import numpy as np

from htdata.fsutil import sha256_file, write_json_atomic
from htdata.manifest import (INDEX_DTYPE, MANIFEST_FILE, SHARDS_DIR,
                             SIZE_FIELDS)
from htdata.resources import validate_json
from htdata.shardio import BLOCK, member_offsets

HANDS = ("left", "right")
CANVAS = 224
CHECKS = ("structure", "content", "time", "sensors", "splits")
CONTACT_THRESHOLD = 0.02      # a pixel above this counts towards contact area
SATURATION_LEVEL = 0.999      # half precision: 1.0 is exact, 0.999 leaves round-off room
SATURATED_WARN_FRACTION = 0.05
FPS_TOLERANCE = 0.05
GAP_FACTOR = 1.5
DEFAULT_MAX_SKEW_MS = 20.0
HIST_BINS = 20


class Check:
    """Failures and warnings of one named check; listing is capped, counting is not."""

    def __init__(self, name: str, max_listed: int):
        self.name = name
        self.max_listed = max_listed
        self.checked: Counter = Counter()
        self.failures: list[dict] = []
        self.failure_counts: Counter = Counter()
        self.warnings: list[dict] = []
        self.warning_counts: Counter = Counter()
        self.skipped: list[str] = []

    def fail(self, what: str, message: str, **where) -> None:
        self.failure_counts[what] += 1
        if len(self.failures) < self.max_listed:
            self.failures.append({"what": what, "message": message, **where})

    def warn(self, what: str, message: str, **where) -> None:
        self.warning_counts[what] += 1
        if len(self.warnings) < self.max_listed:
            self.warnings.append({"what": what, "message": message, **where})

    def merge(self, records: dict) -> None:
        """Add failures/warnings/checked produced by a worker."""
        for rec in records.get("failures", []):
            self.fail(**rec)
        for rec in records.get("warnings", []):
            self.warn(**rec)
        self.checked.update(records.get("checked", {}))

    @property
    def ok(self) -> bool:
        return not self.failure_counts

    def to_dict(self) -> dict:
        return {
            "status": "skipped" if self.skipped and not self.checked and self.ok else
                      ("pass" if self.ok else "fail"),
            "checked": dict(self.checked),
            "failure_count": int(sum(self.failure_counts.values())),
            "failure_counts": dict(self.failure_counts),
            "warning_count": int(sum(self.warning_counts.values())),
            "warning_counts": dict(self.warning_counts),
            "failures": self.failures,
            "warnings": self.warnings,
            "skipped": self.skipped,
        }


class Recorder:
    """Worker-side stand-in for Check: plain lists, merged by the parent."""

    def __init__(self):
        self.failures: list[dict] = []
        self.warnings: list[dict] = []
        self.checked: Counter = Counter()

    def fail(self, what: str, message: str, **where) -> None:
        self.failures.append({"what": what, "message": message, **where})

    def warn(self, what: str, message: str, **where) -> None:
        self.warnings.append({"what": what, "message": message, **where})

    def to_dict(self) -> dict:
        return {"failures": self.failures, "warnings": self.warnings, "checked": dict(self.checked)}


@dataclass
class ValidateConfig:
    split: str | None = None
    deep: bool = False
    sample_frac: float = 0.05
    seed: int = 0
    workers: int | None = None   # None: all cores for --deep, 1 otherwise
    max_listed: int = 1000       # failures listed per check (all are counted)

    def validate(self) -> None:
        if not (0.0 < self.sample_frac <= 1.0):
            raise ValueError(f"--sample-frac must be in (0, 1], got {self.sample_frac}")
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"--workers must be >= 1, got {self.workers}")
        if self.max_listed < 1:
            raise ValueError(f"max_listed must be >= 1, got {self.max_listed}")

    def resolved_workers(self, n_shards: int) -> int:
        wanted = self.workers if self.workers is not None else (os.cpu_count() or 1) if self.deep else 1
        return max(1, min(wanted, max(n_shards, 1)))


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
    coverage: dict[str, np.ndarray] = field(default_factory=dict)   # episode_id:hand -> (224,224) bool
    region_map: np.ndarray | None = None


# ----------------------------------------------------------------------------- shard worker




def _header_name_size(header: bytes) -> tuple[str, int]:
    """(name, size) of a USTAR header block; raises ValueError on a bad checksum."""
    import tarfile

    info = tarfile.TarInfo.frombuf(header, "utf-8", "strict")
    return info.name, info.size


def _decode_exr_half(data: bytes) -> tuple[np.ndarray, str]:
    import OpenEXR

    channels = OpenEXR.File(io.BytesIO(data)).channels()
    if "Y" not in channels:
        raise ValueError(f"EXR has no channel 'Y' (channels: {sorted(channels)})")
    pixels = np.asarray(channels["Y"].pixels)
    return pixels, str(pixels.dtype)


@dataclass
class CoverageGeometry:
    """Per-layout lookups computed once per shard, so each map costs a few vector ops."""
    mask: np.ndarray        # (224,224) bool covered pixels
    idx: np.ndarray         # flat indices of covered pixels
    labels: np.ndarray      # region id of each covered pixel (0 = outside every region)
    counts: np.ndarray      # covered pixels per region id
    n_covered: int


def coverage_geometry(coverage: np.ndarray, region_map: np.ndarray | None) -> CoverageGeometry:
    mask = np.asarray(coverage, bool)
    idx = np.flatnonzero(mask.ravel())
    regions = np.zeros(mask.shape, np.uint8) if region_map is None else region_map
    labels = regions.ravel()[idx].astype(np.intp)
    counts = np.bincount(labels, minlength=int(regions.max()) + 1)
    return CoverageGeometry(mask, idx, labels, counts, int(idx.size))


def region_means(covered_values: np.ndarray, geo: CoverageGeometry) -> np.ndarray:
    """Mean value per region id over covered pixels; NaN for a region with no covered pixel."""
    sums = np.bincount(geo.labels, weights=covered_values, minlength=geo.counts.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(geo.counts > 0, sums / np.maximum(geo.counts, 1), np.nan)
    means[0] = np.nan  # label 0: covered but outside the template's regions
    return means


def value_histogram(values: np.ndarray) -> np.ndarray:
    """HIST_BINS equal bins over [0,1] (1.0 in the last bin), like np.histogram but ~5x cheaper."""
    bins = np.minimum((values * HIST_BINS).astype(np.intp), HIST_BINS - 1)
    return np.bincount(bins, minlength=HIST_BINS)


def _check_content(geometry: dict[str, CoverageGeometry], rec: Recorder, key: str, where: dict,
                   members: dict[str, bytes], hands_present: list[str], sensor: dict) -> None:
    """Decode one sample's members and check shapes, dtypes, values and coverage."""
    from htdata.codec import decode_rgb

    rec.checked["samples_decoded"] += 1
    if "rgb.jpg" in members:
        try:
            rgb = decode_rgb(members["rgb.jpg"], where=f"{key}.rgb.jpg")
            if rgb.shape != (CANVAS, CANVAS, 3) or rgb.dtype != np.uint8:
                rec.fail("rgb_shape", f"{key}.rgb.jpg decodes to {rgb.shape} {rgb.dtype}",
                         **where, expected="(224, 224, 3) uint8", found=f"{rgb.shape} {rgb.dtype}")
        except ValueError as exc:
            rec.fail("rgb_decode", str(exc), **where)
    else:
        rec.fail("rgb_missing", f"{key}: no rgb.jpg member", **where)
    for hand in hands_present:
        member = f"tactile_{hand}.exr"
        rec.checked["tactile_maps_decoded"] += 1
        try:
            pixels, dtype = _decode_exr_half(members[member])
        except Exception as exc:  # OpenEXR raises several types for corrupt bytes
            rec.fail("tactile_decode", f"{key}.{member}: does not decode: {exc}", **where, hand=hand)
            continue
        if pixels.shape != (CANVAS, CANVAS) or dtype != "float16":
            rec.fail("tactile_shape", f"{key}.{member}: {pixels.shape} {dtype}", **where, hand=hand,
                     expected="(224, 224) float16", found=f"{pixels.shape} {dtype}")
            continue
        tmap = pixels.astype(np.float32)
        finite = np.isfinite(tmap)
        if not finite.all():
            bad = np.argwhere(~finite)[0]
            rec.fail("tactile_nonfinite",
                     f"{key}.{member}: {int((~finite).sum())} NaN/Inf value(s), first at row {bad[0]}, "
                     f"col {bad[1]}", **where, hand=hand, expected="finite",
                     found=f"{int(np.isnan(tmap).sum())} NaN, {int(np.isinf(tmap).sum())} Inf")
            continue
        lo, hi = float(tmap.min()), float(tmap.max())
        if lo < 0.0 or hi > 1.0:
            rec.fail("tactile_range", f"{key}.{member}: values outside [0,1]", **where, hand=hand,
                     expected="[0, 1]", found=f"[{lo:.6g}, {hi:.6g}]")
        geo = geometry.get(f"{where['episode']}:{hand}")
        if geo is None:
            rec.fail("coverage_missing", f"{key}: no coverage map for the {hand} hand's layout",
                     **where, hand=hand)
            continue
        flat = tmap.ravel()
        covered = flat[geo.idx]
        n_outside = int(np.count_nonzero(flat)) - int(np.count_nonzero(covered))
        if n_outside:
            bad = np.argwhere((~geo.mask) & (tmap != 0))[0]
            rec.fail("tactile_outside_coverage",
                     f"{key}.{member}: {n_outside} non-zero pixel(s) outside the layout's "
                     f"coverage, first at row {bad[0]}, col {bad[1]}", **where, hand=hand,
                     expected="0 outside coverage", found=f"{n_outside} pixels")
        acc = sensor.setdefault(f"{where['episode']}:{hand}", {
            "frames": [], "region_means": [], "max": 0.0, "saturated": 0, "covered": 0})
        acc["frames"].append(where["frame"])
        acc["region_means"].append(region_means(covered, geo))
        acc["max"] = max(acc["max"], hi)
        acc["saturated"] += int(np.count_nonzero(covered >= SATURATION_LEVEL))
        acc["covered"] += geo.n_covered
        sensor.setdefault("_contact_area", []).append(
            float(np.count_nonzero(covered > CONTACT_THRESHOLD)) / max(geo.n_covered, 1))
        sensor.setdefault("_pressure_hist", np.zeros(HIST_BINS, np.int64))
        sensor["_pressure_hist"] += value_histogram(covered[covered > 0])
    for hand in HANDS:
        member = f"bend_{hand}.npy"
        if member in members:
            try:
                bend = np.load(io.BytesIO(members[member]), allow_pickle=False)
            except ValueError as exc:
                rec.fail("bend_decode", f"{key}.{member}: {exc}", **where, hand=hand)
                continue
            if bend.ndim != 1 or not np.issubdtype(bend.dtype, np.floating) or not np.isfinite(bend).all():
                rec.fail("bend_values", f"{key}.{member}: expected a finite 1-D float vector",
                         **where, hand=hand, found=f"{bend.shape} {bend.dtype}")


def check_shard(job: ShardJob) -> dict:
    """Structure (+ content when asked) of one shard. Returns plain data for the parent."""
    structure, content = Recorder(), Recorder()
    n = len(job.rows)
    by_array: dict[int, CoverageGeometry] = {}
    for cov in job.coverage.values():
        if id(cov) not in by_array:
            by_array[id(cov)] = coverage_geometry(cov, job.region_map)
    geometry = {k: by_array[id(cov)] for k, cov in job.coverage.items()}
    timestamps = {"row": job.row_ids.copy(), "t_rgb": np.zeros(n, np.int64),
                  "ok": np.zeros(n, bool)}
    for hand in HANDS:
        timestamps[f"t_{hand}"] = np.zeros(n, np.int64)
        timestamps[f"has_{hand}"] = np.zeros(n, bool)
    hashes: list[tuple[int, str]] = []
    sensor: dict = {}
    base = {"shard": job.name}
    if not os.path.isfile(job.path):
        structure.fail("shard_missing", f"shard {job.name} listed in the manifest is missing "
                       f"({n} samples lost)", **base, expected=f"{job.bytes} bytes", found="no file")
        return {"structure": structure.to_dict(), "content": content.to_dict(), "timestamps": timestamps,
                "hashes": hashes, "sensor": sensor}
    size = os.path.getsize(job.path)
    structure.checked["shards"] += 1
    if size != job.bytes:
        structure.fail("shard_size", f"shard {job.name} has {size} bytes, manifest says {job.bytes}"
                       + (" (truncated)" if size < job.bytes else ""), **base,
                       expected=job.bytes, found=size)
    digest = sha256_file(job.path)
    if digest != job.sha256:
        structure.fail("shard_sha256", f"shard {job.name}: sha256 differs from the manifest "
                       f"(content changed or corrupted)", **base, expected=job.sha256, found=digest)

    suffixes = list(SIZE_FIELDS)
    with open(job.path, "rb") as f:
        for i in range(n):
            row = job.rows[i]
            eid = job.episode_ids[i]
            key = f"{eid}__{int(row['frame']):06d}"
            where = {**base, "key": key, "episode": eid, "frame": int(row["frame"]),
                     "sample": int(job.row_ids[i])}
            present = [s for s in suffixes if int(row[SIZE_FIELDS[s]]) > 0]
            sizes = [int(row[SIZE_FIELDS[s]]) for s in present]
            data_offsets = member_offsets(int(row["offset"]), sizes)
            members: dict[str, bytes] = {}
            need_bytes = bool(job.decode[i]) or job.content_hash
            bad_member = False
            for suffix, size_expected, data_off in zip(present, sizes, data_offsets):
                structure.checked["members"] += 1
                f.seek(data_off - BLOCK)
                header = f.read(BLOCK)
                expected_name = f"{key}.{suffix}"
                if len(header) < BLOCK:
                    structure.fail("member_truncated", f"{job.name}: header of {expected_name} at "
                                   f"offset {data_off - BLOCK} lies past the end of the shard",
                                   **where, expected=expected_name, found=f"{len(header)} bytes")
                    bad_member = True
                    break
                try:
                    name, tar_size = _header_name_size(header)
                except Exception as exc:  # tarfile raises its own HeaderError family
                    structure.fail("member_header", f"{job.name}: no valid tar header at offset "
                                   f"{data_off - BLOCK} for {expected_name}: {exc}", **where,
                                   expected=expected_name, found="invalid header")
                    bad_member = True
                    break
                if name != expected_name or tar_size != size_expected:
                    structure.fail("member_offset", f"{job.name}: index offset {data_off - BLOCK} "
                                   f"points at {name!r} ({tar_size} bytes)", **where,
                                   expected=f"{expected_name} ({size_expected} bytes)",
                                   found=f"{name} ({tar_size} bytes)")
                    bad_member = True
                    break
                if suffix == "json" or need_bytes:
                    data = f.read(size_expected)
                    if len(data) != size_expected:
                        structure.fail("member_truncated", f"{job.name}: {expected_name} is cut short",
                                       **where, expected=size_expected, found=len(data))
                        bad_member = True
                        break
                    members[suffix] = data
            structure.checked["samples"] += 1
            if bad_member:
                continue
            meta = _check_sample_json(structure, members["json"], key, eid, int(row["frame"]), row, where)
            if meta is None:
                continue
            timestamps["ok"][i] = True
            timestamps["t_rgb"][i] = meta["t_rgb_ns"]
            for hand in HANDS:
                if hand in meta["t_tactile_ns"]:
                    timestamps[f"t_{hand}"][i] = meta["t_tactile_ns"][hand]
                    timestamps[f"has_{hand}"][i] = True
            hands_present = [h for h in HANDS if f"tactile_{h}.exr" in members]
            if job.content_hash:
                h = hashlib.sha256()
                for suffix in ("rgb.jpg", "tactile_left.exr", "tactile_right.exr"):
                    h.update(suffix.encode() + b"\0" + members.get(suffix, b""))
                hashes.append((int(job.row_ids[i]), h.hexdigest()))
            if job.decode[i]:
                _check_content(geometry, content, key, where, members, hands_present, sensor)
    return {"structure": structure.to_dict(), "content": content.to_dict(), "timestamps": timestamps,
            "hashes": hashes, "sensor": sensor}


@lru_cache(maxsize=1)
def _sample_validator():
    """One compiled validator per process: building it per sample costs ~1 ms each."""
    import jsonschema

    from htdata.resources import load_schema

    return jsonschema.Draft202012Validator(load_schema("sample"))


def _check_sample_json(rec: Recorder, data: bytes, key: str, eid: str, frame: int, row,
                       where: dict) -> dict | None:
    try:
        meta = json.loads(data)
        if not _sample_validator().is_valid(meta):
            validate_json(meta, "sample", where=f"{key}.json")  # raises with the first error
    except (ValueError, UnicodeDecodeError) as exc:
        rec.fail("sample_json", f"{key}.json: {exc}", **where)
        return None
    rec.checked["sample_json"] += 1
    for field_name, expected in (("key", key), ("episode_id", eid), ("frame_index", frame)):
        if meta[field_name] != expected:
            rec.fail("sample_json_mismatch", f"{key}.json: {field_name} disagrees with the index",
                     **where, expected=expected, found=meta[field_name])
    for hand in HANDS:
        has_map = int(row[SIZE_FIELDS[f"tactile_{hand}.exr"]]) > 0
        if bool(meta["hands"][hand]) != has_map:
            rec.fail("sample_hands", f"{key}.json: hands.{hand}={meta['hands'][hand]} but the "
                     f"tactile_{hand}.exr member is {'present' if has_map else 'absent'}",
                     **where, expected=has_map, found=meta["hands"][hand])
        if has_map and hand not in meta["t_tactile_ns"]:
            rec.fail("sample_json", f"{key}.json: no t_tactile_ns for the {hand} hand", **where)
            return None
    return meta


# ----------------------------------------------------------------------------- dataset level


@dataclass
class Loaded:
    root: Path
    manifest: dict
    manifest_bytes: bytes
    episodes: list[dict]
    index: np.ndarray


def _load(root: Path, check: Check) -> Loaded | None:
    """Read and schema-check manifest, episodes and index; None when nothing more can be checked."""
    mpath = root / MANIFEST_FILE
    if not mpath.is_file():
        check.fail("manifest_missing", f"{mpath}: no dataset.json (not a committed dataset)",
                   file=str(mpath))
        return None
    manifest_bytes = mpath.read_bytes()
    try:
        manifest = json.loads(manifest_bytes)
        validate_json(manifest, "manifest", where=str(mpath))
    except ValueError as exc:
        check.fail("manifest_schema", str(exc), file=MANIFEST_FILE)
        return None
    check.checked["manifest"] += 1

    epath = root / manifest["episodes_file"]
    if not epath.is_file():
        check.fail("episodes_missing", f"{epath} missing", file=manifest["episodes_file"])
        return None
    ebytes = epath.read_bytes()
    found = hashlib.sha256(ebytes).hexdigest()
    if found != manifest["episodes_sha256"]:
        check.fail("episodes_sha256", f"{epath.name}: sha256 differs from the manifest",
                   file=epath.name, expected=manifest["episodes_sha256"], found=found)
    episodes = []
    for line_no, line in enumerate(ebytes.decode("utf-8", "replace").splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            validate_json(rec, "episode", where=f"{epath.name}:{line_no}")
        except ValueError as exc:
            check.fail("episode_schema", str(exc), file=epath.name, line=line_no)
            return None
        episodes.append(rec)
        check.checked["episode_records"] += 1
    ids = Counter(ep["episode_id"] for ep in episodes)
    for eid, c in ids.items():
        if c > 1:
            check.fail("episode_duplicate", f"episode id {eid!r} appears {c} times", episode=eid)

    ipath = root / manifest["index_file"]
    if not ipath.is_file():
        check.fail("index_missing", f"{ipath} missing", file=manifest["index_file"])
        return None
    found = hashlib.sha256(ipath.read_bytes()).hexdigest()
    if found != manifest["index_sha256"]:
        check.fail("index_sha256", f"{ipath.name}: sha256 differs from the manifest",
                   file=ipath.name, expected=manifest["index_sha256"], found=found)
    try:
        index = np.load(ipath, allow_pickle=False)
    except ValueError as exc:
        check.fail("index_unreadable", f"{ipath}: {exc}", file=ipath.name)
        return None
    if index.dtype != INDEX_DTYPE:
        check.fail("index_dtype", f"{ipath.name}: wrong dtype", file=ipath.name,
                   expected=str(INDEX_DTYPE), found=str(index.dtype))
        return None
    return Loaded(root, manifest, manifest_bytes, episodes, index)


def group_rows(values: np.ndarray, n_groups: int) -> list[np.ndarray]:
    """Row positions holding each value 0..n_groups-1 (ascending): O(N log N), not one scan per group."""
    order = np.argsort(values, kind="stable")
    bounds = np.searchsorted(values[order], np.arange(n_groups + 1))
    return [order[bounds[g]:bounds[g + 1]] for g in range(n_groups)]


def _check_index(ds: Loaded, check: Check) -> bool:
    """Counts, contiguity, order and key uniqueness from index.npy alone. False if rows are unusable."""
    m, rows, eps = ds.manifest, ds.index, ds.episodes
    n, n_shards, n_eps = len(rows), len(m["shards"]), len(eps)
    check.checked["index_rows"] += n
    for what, expected, found in (("samples", m["counts"]["samples"], n),
                                  ("episodes", m["counts"]["episodes"], n_eps),
                                  ("shards", m["counts"]["shards"], n_shards)):
        if expected != found:
            check.fail("count_" + what, f"manifest counts.{what} = {expected}, dataset holds {found}",
                       expected=expected, found=found)
    usable = True
    if n and (rows["shard"].max() >= n_shards or rows["episode"].max() >= n_eps):
        bad = np.flatnonzero((rows["shard"] >= n_shards) | (rows["episode"] >= n_eps))
        check.fail("index_range", f"{bad.size} index rows name a shard or episode that does not exist, "
                   f"first at row {bad[0]}", sample=int(bad[0]),
                   expected=f"shard < {n_shards}, episode < {n_eps}",
                   found=f"shard {int(rows['shard'][bad[0]])}, episode {int(rows['episode'][bad[0]])}")
        usable = False
    if not usable:
        return False
    per_shard = np.bincount(rows["shard"], minlength=n_shards)
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
    if n and np.any(np.diff(rows["shard"].astype(np.int64)) < 0):
        bad = int(np.flatnonzero(np.diff(rows["shard"].astype(np.int64)) < 0)[0]) + 1
        check.fail("index_order", f"index row {bad} goes back to an earlier shard", sample=bad)
    same_shard = rows["shard"][1:] == rows["shard"][:-1]
    back = np.flatnonzero(same_shard & (rows["offset"][1:] <= rows["offset"][:-1])) + 1
    for r in back[:check.max_listed]:
        check.fail("offset_order", f"index row {r}: offset does not increase within its shard",
                   sample=int(r), shard=m["shards"][int(rows["shard"][r])]["name"],
                   expected=f"> {int(rows['offset'][r - 1])}", found=int(rows["offset"][r]))

    # episode contiguity + frames 0..n-1 + num_frames / first_sample
    keys = rows["episode"].astype(np.int64) * (1 << 32) + rows["frame"].astype(np.int64)
    uniq, counts = np.unique(keys, return_counts=True)
    for k in uniq[counts > 1][:check.max_listed]:
        eid = eps[int(k >> 32)]["episode_id"]
        key = f"{eid}__{int(k & 0xFFFFFFFF):06d}"
        check.fail("key_duplicate", f"sample key {key} appears {int(counts[uniq == k][0])} times",
                   key=key, episode=eid, frame=int(k & 0xFFFFFFFF))
    check.checked["keys"] += int(uniq.size)
    per_ep = np.bincount(rows["episode"], minlength=n_eps)
    ep_rows = group_rows(rows["episode"], n_eps)
    for pos, ep in enumerate(eps):
        eid, count = ep["episode_id"], int(per_ep[pos])
        where = {"episode": eid}
        if count != ep["num_frames"]:
            check.fail("episode_samples", f"episode {eid}: num_frames {ep['num_frames']} but the index "
                       f"holds {count} samples", **where, expected=ep["num_frames"], found=count)
        if count == 0:
            continue
        pos_rows = ep_rows[pos]
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
        shard_names = sorted({m["shards"][s]["name"] for s in np.unique(rows["shard"][pos_rows])})
        if sorted(ep["shards"]) != shard_names:
            check.fail("episode_shards", f"episode {eid}: shards list disagrees with the index", **where,
                       expected=shard_names, found=sorted(ep["shards"]))
        for hand in HANDS:
            col = rows[f"size_tactile_{hand}"][pos_rows]
            has = hand in ep["hands"]
            if has and not (col > 0).all():
                r = int(pos_rows[np.flatnonzero(col == 0)[0]])
                check.fail("hand_member", f"episode {eid} has a {hand} hand but index row {r} has no "
                           f"tactile_{hand}.exr", **where, sample=r, frame=int(rows['frame'][r]))
            if not has and (col > 0).any():
                r = int(pos_rows[np.flatnonzero(col > 0)[0]])
                check.fail("hand_member", f"episode {eid} has no {hand} hand but index row {r} has a "
                           f"tactile_{hand}.exr", **where, sample=r, frame=int(rows['frame'][r]))
    return True


def _check_shard_files(ds: Loaded, check: Check) -> None:
    listed = {s["name"] for s in ds.manifest["shards"]}
    shard_dir = ds.root / SHARDS_DIR
    present = sorted(p.name for p in shard_dir.iterdir()) if shard_dir.is_dir() else []
    for name in present:
        if name.endswith(".tar") and name not in listed:
            check.fail("shard_extra", f"{SHARDS_DIR}/{name} is not listed in the manifest", shard=name)
        elif name.endswith(".tmp"):
            check.warn("shard_temp", f"{SHARDS_DIR}/{name}: temp file left by an interrupted write",
                       shard=name)


def _layout_maps(ds: Loaded, check: Check) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    from htdata.manifest import decode_png_u8

    coverage = {}
    for layout_id, entry in ds.manifest["layouts"].items():
        path = ds.root / entry["coverage"]
        try:
            coverage[layout_id] = decode_png_u8(path.read_bytes(), str(path)) > 0
        except (OSError, ValueError) as exc:
            check.fail("coverage_unreadable", f"layout {layout_id}: {exc}", file=entry["coverage"])
    region_map = None
    path = ds.root / ds.manifest["canonical"]["regions"]
    try:
        region_map = decode_png_u8(path.read_bytes(), str(path))
    except (OSError, ValueError) as exc:
        check.fail("regions_unreadable", f"canonical region map: {exc}",
                   file=ds.manifest["canonical"]["regions"])
    return coverage, region_map


def _decode_mask(ds: Loaded, cfg: ValidateConfig) -> np.ndarray:
    """Rows whose content is decoded: all with --deep, else a seeded fraction + each episode's first frame."""
    n = len(ds.index)
    if cfg.deep:
        return np.ones(n, bool)
    rng = np.random.default_rng(cfg.seed)
    mask = rng.random(n) < cfg.sample_frac
    mask |= ds.index["frame"] == 0
    return mask


def _shard_jobs(ds: Loaded, cfg: ValidateConfig, decode: np.ndarray, coverage: dict, region_map,
                content_hash: bool) -> list[ShardJob]:
    eids = [ep["episode_id"] for ep in ds.episodes]
    cov_by_ep = {}
    for ep in ds.episodes:
        for hand, layout_id in ep["layouts"].items():
            if layout_id in coverage:
                cov_by_ep[f"{ep['episode_id']}:{hand}"] = coverage[layout_id]
    jobs = []
    rows = ds.index
    shard_rows_of = group_rows(rows["shard"], len(ds.manifest["shards"]))
    for pos, entry in enumerate(ds.manifest["shards"]):
        ids = shard_rows_of[pos]
        shard_rows = np.asarray(rows[ids])
        ep_ids = [eids[int(e)] for e in shard_rows["episode"]]
        needed = {f"{e}:{h}" for e in set(ep_ids) for h in HANDS}
        jobs.append(ShardJob(
            shard_pos=pos, name=entry["name"], path=str(ds.root / SHARDS_DIR / entry["name"]),
            sha256=entry["sha256"], bytes=entry["bytes"], rows=shard_rows, row_ids=ids,
            episode_ids=ep_ids, decode=decode[ids], content_hash=content_hash,
            coverage={k: v for k, v in cov_by_ep.items() if k in needed}, region_map=region_map))
    return jobs


def _run_jobs(jobs: list[ShardJob], workers: int) -> list[dict]:
    if workers <= 1 or len(jobs) <= 1:
        return [check_shard(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(check_shard, jobs))


def _max_skew_ns(ds: Loaded, ep: dict) -> tuple[int, str]:
    """Sync tolerance of an episode: its sync report, else its source pipeline, else the default."""
    sync = ep.get("sync") or {}
    if isinstance(sync.get("max_skew_ns"), (int, float)):
        return int(sync["max_skew_ns"]), "episode sync report"
    for src in ds.manifest.get("sources", []):
        names = {src.get("name"), (src.get("adapter") or {}).get("name")}
        if ep["source"] in names and isinstance((src.get("sync") or {}).get("max_skew_ms"), (int, float)):
            return int(round(src["sync"]["max_skew_ms"] * 1e6)), f"pipeline {src.get('name')}"
    return int(DEFAULT_MAX_SKEW_MS * 1e6), "default"


def _check_time(ds: Loaded, ts: dict, check: Check) -> None:
    rows = ds.index
    ep_rows = group_rows(rows["episode"], len(ds.episodes))
    for pos, ep in enumerate(ds.episodes):
        eid = ep["episode_id"]
        sel = ep_rows[pos][ts["ok"][ep_rows[pos]]]
        if sel.size == 0:
            check.skipped.append(f"{eid}: no readable sample JSON")
            continue
        sel = sel[np.argsort(rows["frame"][sel], kind="stable")]
        frames = rows["frame"][sel].astype(np.int64)
        check.checked["episodes"] += 1
        t_rgb = ts["t_rgb"][sel]
        d = np.diff(t_rgb)
        for r in np.flatnonzero(d <= 0)[:check.max_listed]:
            fr = int(frames[r + 1])
            check.fail("rgb_not_increasing", f"episode {eid}: t_rgb_ns of frame {fr} is not after frame "
                       f"{int(frames[r])}", episode=eid, frame=fr,
                       key=f"{eid}__{fr:06d}", expected=f"> {int(t_rgb[r])}", found=int(t_rgb[r + 1]))
        for hand in ep["hands"]:
            has = ts[f"has_{hand}"][sel]
            t = ts[f"t_{hand}"][sel][has]
            fr_h = frames[has]
            dt = np.diff(t)
            for r in np.flatnonzero(dt < 0)[:check.max_listed]:
                fr = int(fr_h[r + 1])
                check.fail("tactile_not_increasing", f"episode {eid}: {hand} tactile time of frame {fr} "
                           f"goes back", episode=eid, frame=fr, hand=hand, key=f"{eid}__{fr:06d}",
                           expected=f">= {int(t[r])}", found=int(t[r + 1]))
            repeats = int((dt == 0).sum())
            if repeats:
                check.warn("tactile_repeated", f"episode {eid}: {repeats} RGB frame(s) share a {hand} "
                           f"tactile frame with the previous one", episode=eid, hand=hand, count=repeats)
            tol, tol_from = _max_skew_ns(ds, ep)
            skew = t_rgb[has] - t
            over = np.flatnonzero(np.abs(skew) > tol)
            check.checked["skews"] += int(skew.size)
            for r in over[:check.max_listed]:
                fr = int(fr_h[r])
                check.fail("sync_skew", f"episode {eid} frame {fr}: |t_rgb - t_{hand}| = {abs(int(skew[r]))} "
                           f"ns exceeds the tolerance ({tol} ns, {tol_from})", episode=eid, frame=fr,
                           hand=hand, key=f"{eid}__{fr:06d}", expected=f"<= {tol}", found=int(skew[r]))
        if d.size and (d > 0).all():
            period = float(np.median(d))
            measured = 1e9 / period
            dev = abs(measured - ep["fps"]) / ep["fps"]
            if dev > FPS_TOLERANCE:
                check.warn("fps_deviation", f"episode {eid}: measured {measured:.3f} fps vs recorded "
                           f"{ep['fps']}", episode=eid, expected=ep["fps"], found=round(measured, 3))
            gaps = np.flatnonzero(d > GAP_FACTOR * 1e9 / ep["fps"])
            if gaps.size:
                check.warn("gap", f"episode {eid}: {gaps.size} gap(s) over {GAP_FACTOR} frame periods, "
                           f"largest {int(d.max())} ns after frame {int(frames[int(np.argmax(d))])}",
                           episode=eid, count=int(gaps.size), found=int(d.max()))


def _check_sensors(sensor: dict, check: Check) -> None:
    for name in sorted(k for k in sensor if not k.startswith("_")):
        eid, hand = name.rsplit(":", 1)
        acc = sensor[name]
        check.checked["episode_hands"] += 1
        where = {"episode": eid, "hand": hand}
        if acc["max"] == 0.0:
            check.warn("all_zero", f"episode {eid}: every decoded {hand} tactile map is all zero "
                       f"({len(acc['frames'])} frames)", **where, count=len(acc["frames"]))
            continue
        frac = acc["saturated"] / max(acc["covered"], 1)
        if frac > SATURATED_WARN_FRACTION:
            check.warn("saturated", f"episode {eid}: {frac:.1%} of covered {hand} pixels saturated",
                       **where, found=round(frac, 4))
        if len(acc["region_means"]) >= 2:
            means = np.stack(acc["region_means"])            # (frames, regions+1)
            valid = np.isfinite(means).all(axis=0)
            valid[0] = False
            constant = valid & (np.ptp(np.where(np.isfinite(means), means, 0), axis=0) == 0)
            dead = np.flatnonzero(constant & (means[0] == 0))
            stuck = np.flatnonzero(constant & (means[0] != 0))
            if dead.size:
                check.warn("dead_regions", f"episode {eid}: {dead.size} {hand} region(s) stay 0 over "
                           f"{len(means)} frames: ids {dead.tolist()}", **where, count=int(dead.size),
                           regions=dead.tolist())
            if stuck.size:
                check.warn("stuck_regions", f"episode {eid}: {stuck.size} {hand} region(s) never change "
                           f"over {len(means)} frames: ids {stuck.tolist()}", **where,
                           count=int(stuck.size), regions=stuck.tolist())


def _check_splits(ds: Loaded, name: str, hashes: dict[int, str], check: Check) -> dict | None:
    path = ds.root / "splits" / f"{name}.json"
    if not path.is_file():
        known = sorted(p.stem for p in (ds.root / "splits").glob("*.json")) if (ds.root / "splits").is_dir() else []
        check.fail("split_missing", f"{path} not found; known splits: {', '.join(known) or '(none)'}",
                   file=str(path))
        return None
    try:
        doc = json.loads(path.read_text())
        validate_json(doc, "split", where=str(path))
    except ValueError as exc:
        check.fail("split_schema", str(exc), file=str(path))
        return None
    manifest_sha = hashlib.sha256(ds.manifest_bytes).hexdigest()
    if doc["manifest_sha256"] != manifest_sha:
        check.fail("split_manifest", f"split {name} was made from another dataset.json",
                   expected=doc["manifest_sha256"], found=manifest_sha)
    by_id = {ep["episode_id"]: ep for ep in ds.episodes}
    part_of: dict[str, list[str]] = defaultdict(list)
    for part in ("train", "test", "ood"):
        for eid in doc["parts"][part]["episodes"]:
            part_of[eid].append(part)
            if eid not in by_id:
                check.fail("split_unknown_episode", f"split {name}: {part} lists unknown episode {eid}",
                           episode=eid, part=part)
    for eid, parts in part_of.items():
        if len(parts) > 1:
            check.fail("episode_in_two_parts", f"episode {eid} is in {' and '.join(parts)}",
                       episode=eid, found=parts)
    for eid in by_id:
        if eid not in part_of:
            check.fail("episode_in_no_part", f"episode {eid} is in no part of split {name}", episode=eid)
    ood_tasks = set(doc["params"]["ood_tasks"])
    for part in ("train", "test"):
        for eid in doc["parts"][part]["episodes"]:
            if eid in by_id and by_id[eid]["task"] in ood_tasks:
                check.fail("ood_task_leak", f"episode {eid} of OOD task {by_id[eid]['task']} is in {part}",
                           episode=eid, part=part, task=by_id[eid]["task"])
    for eid, ep in by_id.items():
        if ep["task"] in ood_tasks and "ood" not in part_of.get(eid, []):
            check.fail("ood_task_leak", f"episode {eid} of OOD task {ep['task']} is not in ood",
                       episode=eid, task=ep["task"])
    check.checked["episodes"] += len(part_of)

    # stated counts and ratios
    frames = {p: sum(by_id[e]["num_frames"] for e in doc["parts"][p]["episodes"] if e in by_id)
              for p in ("train", "test", "ood")}
    for part in ("train", "test", "ood"):
        if doc["parts"][part]["frames"] != frames[part]:
            check.fail("split_frames", f"split {name}: {part} states {doc['parts'][part]['frames']} frames",
                       part=part, expected=frames[part], found=doc["parts"][part]["frames"])
    n = {p: len(doc["parts"][p]["episodes"]) for p in ("train", "test", "ood")}
    achieved = {
        "test_of_in_distribution": {"episodes": n["test"] / max(n["train"] + n["test"], 1),
                                    "frames": frames["test"] / max(frames["train"] + frames["test"], 1)},
        "ood_of_all": {"episodes": n["ood"] / max(sum(n.values()), 1),
                       "frames": frames["ood"] / max(sum(frames.values()), 1)},
    }
    for ratio, vals in achieved.items():
        for unit, val in vals.items():
            stated = doc["ratios"][ratio][unit]
            if abs(stated - val) > 1e-9:
                check.fail("split_ratio", f"split {name}: {ratio}.{unit} states {stated:.6f}",
                           expected=round(val, 6), found=stated)
    asked = doc["params"]["test_ratio"]
    got = achieved["test_of_in_distribution"]["episodes"]
    if abs(got - asked) > max(0.05, 1.0 / max(n["train"] + n["test"], 1)):
        check.warn("split_ratio_far", f"split {name}: test holds {got:.3f} of in-distribution episodes, "
                   f"asked {asked}", expected=asked, found=round(got, 4))

    # byte-identical frames across parts
    if hashes:
        part_by_row = {}
        eids = [ep["episode_id"] for ep in ds.episodes]
        groups: dict[str, list[int]] = defaultdict(list)
        for row, digest in hashes.items():
            groups[digest].append(row)
        for digest, rows in groups.items():
            if len(rows) < 2:
                continue
            labelled = []
            for r in rows:
                eid = eids[int(ds.index["episode"][r])]
                part_by_row[r] = (part_of.get(eid) or ["none"])[0]
                labelled.append((part_by_row[r], f"{eid}__{int(ds.index['frame'][r]):06d}"))
            if len({p for p, _ in labelled}) > 1:
                check.fail("duplicate_frame_across_parts",
                           "byte-identical frame in several parts: "
                           + ", ".join(f"{k} ({p})" for p, k in sorted(labelled)),
                           keys=[k for _, k in sorted(labelled)], parts=sorted({p for p, _ in labelled}),
                           sha256=digest)
        check.checked["frames_hashed"] += len(hashes)
    return doc


def _stats(ds: Loaded, sensor: dict) -> dict:
    rows = ds.index
    per_ep = np.bincount(rows["episode"], minlength=len(ds.episodes)) if len(rows) else np.zeros(0, int)
    by_task: Counter = Counter()
    by_scene: Counter = Counter()
    for pos, ep in enumerate(ds.episodes):
        by_task[ep["task"]] += int(per_ep[pos])
        by_scene[ep["scene"]] += int(per_ep[pos])
    area = np.asarray(sensor.get("_contact_area", []), np.float64)
    edges = np.linspace(0.0, 1.0, HIST_BINS + 1)
    return {
        "frames_per_task": dict(sorted(by_task.items())),
        "frames_per_scene": dict(sorted(by_scene.items())),
        "frames_per_hand": {h: int(np.count_nonzero(rows[f"size_tactile_{h}"])) for h in HANDS},
        "contact_area_histogram": {"bin_edges": edges.tolist(),
                                   "counts": np.histogram(area, bins=edges)[0].tolist(),
                                   "threshold": CONTACT_THRESHOLD, "maps": int(area.size)},
        "pressure_histogram": {"bin_edges": edges.tolist(),
                               "counts": np.asarray(sensor.get("_pressure_hist", np.zeros(HIST_BINS)),
                                                    np.int64).tolist(),
                               "note": "covered pixels with value > 0 over decoded maps"},
    }


def _merge_sensor(into: dict, part: dict) -> None:
    for k, v in part.items():
        if k == "_contact_area":
            into.setdefault(k, []).extend(v)
        elif k == "_pressure_hist":
            into[k] = into.get(k, 0) + v
        elif k in into:  # an episode spanning two shards
            acc = into[k]
            acc["frames"] += v["frames"]
            acc["region_means"] += v["region_means"]
            acc["max"] = max(acc["max"], v["max"])
            acc["saturated"] += v["saturated"]
            acc["covered"] += v["covered"]
        else:
            into[k] = v


def validate_dataset(path, split: str | None = None, deep: bool = False, sample_frac: float = 0.05,
                     seed: int = 0, workers: int | None = None, max_listed: int = 1000) -> dict:
    """Run every check on a committed dataset; returns the report (report["ok"] is the verdict)."""
    cfg = ValidateConfig(split=split, deep=deep, sample_frac=sample_frac, seed=seed, workers=workers,
                         max_listed=max_listed)
    cfg.validate()
    root = Path(path)
    t0 = time.perf_counter()
    checks = {name: Check(name, cfg.max_listed) for name in CHECKS}
    report = {"dataset": str(root), "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "params": {"split": split, "deep": deep, "sample_frac": sample_frac, "seed": seed}}
    ds = _load(root, checks["structure"])
    stats: dict = {}
    if ds is not None and _check_index(ds, checks["structure"]):
        _check_shard_files(ds, checks["structure"])
        coverage, region_map = _layout_maps(ds, checks["content"])
        decode = _decode_mask(ds, cfg)
        jobs = _shard_jobs(ds, cfg, decode, coverage, region_map, content_hash=split is not None)
        n_workers = cfg.resolved_workers(len(jobs))
        report["params"]["workers"] = n_workers
        results = _run_jobs(jobs, n_workers)
        n = len(ds.index)
        ts = {"ok": np.zeros(n, bool), "t_rgb": np.zeros(n, np.int64)}
        for hand in HANDS:
            ts[f"t_{hand}"] = np.zeros(n, np.int64)
            ts[f"has_{hand}"] = np.zeros(n, bool)
        sensor: dict = {}
        hashes: dict[int, str] = {}
        for res in results:
            checks["structure"].merge(res["structure"])
            checks["content"].merge(res["content"])
            r = res["timestamps"]["row"]
            for k in ts:
                ts[k][r] = res["timestamps"][k]
            hashes.update(dict(res["hashes"]))
            _merge_sensor(sensor, res["sensor"])
        _check_time(ds, ts, checks["time"])
        _check_sensors(sensor, checks["sensors"])
        if split is not None:
            _check_splits(ds, split, hashes, checks["splits"])
        stats = _stats(ds, sensor)
    else:
        for name in CHECKS[1:]:
            checks[name].skipped.append("structure could not be read")
    if split is None:
        checks["splits"].skipped.append("no --split given")
    report["checks"] = {name: c.to_dict() for name, c in checks.items()}
    report["stats"] = stats
    report["ok"] = all(c.ok for c in checks.values())
    report["elapsed_s"] = round(time.perf_counter() - t0, 3)
    report["samples"] = int(len(ds.index)) if ds is not None else 0
    return report


def validate_benchmark(path, workers: int | None = None) -> dict:
    """Time a --deep validation: frames (samples) decoded and checked per second."""
    t0 = time.perf_counter()
    report = validate_dataset(path, deep=True, workers=workers)
    elapsed = time.perf_counter() - t0
    return {"frames": report["samples"], "seconds": elapsed,
            "frames_per_s": report["samples"] / elapsed if elapsed > 0 else float("inf"),
            "workers": report["params"].get("workers"), "ok": report["ok"]}


def format_report(report: dict) -> str:
    lines = [f"htdata validate {report['dataset']}: {report['samples']} samples, "
             f"{'deep' if report['params']['deep'] else 'sampled'} content check"]
    for name, c in report["checks"].items():
        checked = ", ".join(f"{v} {k}" for k, v in c["checked"].items()) or "-"
        lines.append(f"  {name:<9} {c['status'].upper():<7} {c['failure_count']} failure(s), "
                     f"{c['warning_count']} warning(s)  [{checked}]")
        for f in c["failures"][:10]:
            lines.append(f"      FAIL {f['what']}: {f['message']}")
        if c["failure_count"] > 10:
            lines.append(f"      ... {c['failure_count'] - 10} more failure(s) in the JSON report")
        for w in c["warnings"][:3]:
            lines.append(f"      warn {w['what']}: {w['message']}")
        if c["warning_count"] > 3:
            lines.append(f"      ... {c['warning_count'] - 3} more warning(s) in the JSON report")
        for s in c["skipped"][:3]:
            lines.append(f"      skipped: {s}")
    lines.append("OK: dataset is sound" if report["ok"] else "FAILED: see failures above")
    return "\n".join(lines)


def write_report(report: dict, path: Path) -> None:

    write_json_atomic(path, report)


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = __doc__
    parser.add_argument("dataset", type=Path, help="committed dataset directory")
    parser.add_argument("--split", default=None, metavar="NAME", help="also check splits/NAME.json")
    parser.add_argument("--deep", action="store_true", help="decode every sample (default: a seeded sample)")
    parser.add_argument("--sample-frac", type=float, default=0.05,
                        help="fraction of samples decoded without --deep (default 0.05)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the content sample")
    parser.add_argument("--json", type=Path, default=None, metavar="REPORT",
                        help="report path (default DATASET/reports/validate.json)")
    parser.add_argument("--workers", type=int, default=None,
                        help="processes over shards (default: all cores with --deep, else 1)")


def run(args: argparse.Namespace) -> int:
    try:
        report = validate_dataset(args.dataset, split=args.split, deep=args.deep,
                                  sample_frac=args.sample_frac, seed=args.seed, workers=args.workers)
    except ValueError as exc:
        print(f"htdata validate: error: {exc}", file=sys.stderr)
        return 2
    out = args.json or Path(args.dataset) / "reports" / "validate.json"
    print(format_report(report))
    if args.json is None and not Path(args.dataset).is_dir():
        print(f"htdata validate: {args.dataset} is not a directory: no report written", file=sys.stderr)
        return 1
    try:
        write_report(report, out)
        print(f"report: {out}")
    except OSError as exc:
        print(f"htdata validate: cannot write report {out}: {exc}", file=sys.stderr)
    return 0 if report["ok"] else 1
