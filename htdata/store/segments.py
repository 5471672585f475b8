"""A version's records as immutable segments (format 4): a write costs what it changes, not the dataset.

Format 3 wrote each version's whole episodes.jsonl and index.npy: a one-episode `rm` on a
dataset of 3M samples wrote 274 MB (bench/REPORT.md, "The dataset at HT-Bench's size"). Format 4
keeps them as segments, runs of consecutive work units (Parts, htdata/store/parts.py), each
two files named by their content and never rewritten:

    segments/<sha16>.json   {"format": "htdata-segment", "units": [{"unit", "shards", "episodes"}]}
    segments/<sha16>.npy    the units' index rows; shard and episode columns local to each unit

A version's manifest lists its segments in order, with each file's sha256 (checked whenever a
file is read). A write makes its units' segments; one whose bytes an earlier version already
wrote has the same name and is not written again. Where a segment ends is decided by its units
(after unit u when u % SEGMENT_UNITS is the last of a run: ingests number units 0, 1, 2 ...), not by
position, so adding, removing or re-packing a unit rewrites the one segment around it and moves no
boundary elsewhere (content-defined chunking, as in rsync or restic). A commit writes
O(units changed x SEGMENT_UNITS) plus a manifest of one entry per segment.

What a reader sees is exactly what format 3 gave: `segmented_records` fills the manifest's shard
list and the episode records (first_sample, shard names) from the segments' JSON;
`load_segment_index` the global index (htdata/store/manifest.py's loaders dispatch to both). The
global index is assembled in memory, or, from INDEX_CACHE_MIN_BYTES (and for a remote dataset
always), once into the local cache (HTDATA_CACHE, where a remote dataset's index goes:
htdata/store/remote.py), checked against the manifest's index_sha256 and memory-mapped from there.
Writers read their parent's parts straight from the segments (`segment_parts`), never the global
index. A segment an interrupted write left behind belongs to no version: `htdata gc` removes it.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path

import numpy as np

from htdata.errors import DatasetError
from htdata.fileio import atomic_open, write_bytes_atomic
from htdata.format.table import INDEX_DTYPE, INDEX_FILE, SEGMENTS_DIR
from htdata.store import storage
from htdata.store.confine import check_manifest_paths, inside
from htdata.store.indexfile import load_index_file, parse_index
from htdata.store.parts import COMPUTED_FIELDS, Part
from htdata.store.storage import cache_dir

SEGMENT_FORMAT = "htdata-segment"
SEGMENT_UNITS = 64              # a segment ends after unit u when u % 64 == 63 ...
MAX_SEGMENT_UNITS = 4 * SEGMENT_UNITS   # ... or when it holds this many (re-packed units renumbered high)
INDEX_CACHE_MIN_BYTES = 64 << 20        # a larger global index is assembled into the cache and mapped
# (samples, shards, episodes) per unit of the segments this process has read, by their records' sha256: the
# index assembly needs only these, not the records again (a segment named by its sha256 never changes)
_UNIT_COUNTS: dict[str, list[tuple[int, int, int]]] = {}


def segmented(manifest: dict) -> bool:
    """True for a version stored as segments (format 4), False for one with its own episodes.jsonl and index.npy.

    Args:
        manifest: the version's manifest as stored.
    """
    return "segments" in manifest


def group_parts(parts: list[Part]) -> list[list[Part]]:
    """The parts of a version cut into segments: after each unit whose number ends a run, or at the cap.

    Args:
        parts: the version's parts, in order.

    Returns:
        Consecutive groups covering `parts`.
    """
    groups: list[list[Part]] = []
    current: list[Part] = []
    for part in parts:
        current.append(part)
        if part.unit % SEGMENT_UNITS == SEGMENT_UNITS - 1 or len(current) >= MAX_SEGMENT_UNITS:
            groups.append(current)
            current = []
    if current:
        groups.append(current)
    return groups


def _place(root: Path, data: bytes, ext: str) -> tuple[str, str, int]:
    """Put `data` at segments/<sha16>.<ext> unless those bytes are there: (relative path, sha256, bytes written)."""
    sha = hashlib.sha256(data).hexdigest()
    rel = f"{SEGMENTS_DIR}/{sha[:16]}.{ext}"
    path = root / rel
    if path.is_file() and path.stat().st_size == len(data):
        return rel, sha, 0      # an earlier version wrote these bytes: content-addressed, shared
    write_bytes_atomic(path, data)
    return rel, sha, len(data)


def write_segments(root: str | os.PathLike, parts: list[Part], episodes: list[dict]) -> tuple[list[dict], int]:
    """Write the segments of a new version (those an earlier version has are reused); returns (entries, bytes written).

    Args:
        root: the dataset root (local).
        parts: the version's parts, in order (rows local to each part).
        episodes: the version's assembled episode records, in order (htdata/store/parts.py `assemble`).

    Returns:
        The manifest's "segments" list, and the bytes this call wrote.
    """
    root = Path(root)
    entries, written, first_episode = [], 0, 0
    for group in group_parts(parts):
        units = []
        for part in group:
            records = episodes[first_episode:first_episode + len(part.episodes)]
            first_episode += len(part.episodes)
            units.append({"unit": part.unit, "shards": part.shards,
                          "episodes": [{k: v for k, v in r.items() if k != "first_sample"} for r in records]})
        doc = json.dumps({"format": SEGMENT_FORMAT, "units": units}, sort_keys=True, separators=(",", ":")).encode()
        buf = io.BytesIO()
        rows = np.concatenate([p.rows for p in group]) if group else np.zeros(0, INDEX_DTYPE)
        np.save(buf, rows.astype(INDEX_DTYPE, copy=False), allow_pickle=False)
        records_rel, records_sha, w1 = _place(root, doc, "json")
        index_rel, index_sha, w2 = _place(root, buf.getvalue(), "npy")
        written += w1 + w2
        entries.append({"records": records_rel, "records_sha256": records_sha, "index": index_rel,
                        "index_sha256": index_sha, "units": len(group), "samples": int(len(rows)),
                        "episodes": sum(len(u["episodes"]) for u in units),
                        "shards": sum(len(u["shards"]) for u in units)})
    return entries, written


def _read_checked(root: str, entry: dict, key: str, where: str) -> tuple[str, bytes]:
    """(path, bytes) of a segment's file `key` ("records" or "index"), checked against its recorded sha256."""
    rel = entry.get(key)
    path = inside(root, rel, f"segments[].{key}")
    try:
        data = storage.read_bytes(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: segment file listed by {where} is missing") from None
    found = hashlib.sha256(data).hexdigest()
    if found != entry.get(f"{key}_sha256"):
        raise DatasetError(f"{path}: sha256 {found[:12]} differs from the {entry.get(f'{key}_sha256', '')[:12]} "
                           f"{where} records: the segment was changed or damaged after it was committed")
    return path, data


def read_segment_doc(root: str | os.PathLike, entry: dict, where: str) -> dict:
    """One segment's JSON document, checked (sha256, format, counts against its manifest entry).

    Args:
        root: the dataset root (path or URL).
        entry: the segment's manifest entry.
        where: the manifest, for messages.

    Returns:
        {"format", "units": [{"unit", "shards", "episodes"}]}.
    """
    path, data = _read_checked(os.fspath(root), entry, "records", where)
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None
    units = doc.get("units") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("format") != SEGMENT_FORMAT or not isinstance(units, list) \
            or not all(isinstance(u, dict) for u in units):
        raise DatasetError(f"{path}: not an {SEGMENT_FORMAT} document")
    # a stranger's segment never names a shard outside shards/ (as a format 3 manifest's list is checked)
    check_manifest_paths({"shards": [s for u in units for s in u.get("shards", [])]}, path)
    for what, key in (("units", None), ("shards", "shards"), ("episodes", "episodes")):
        found = len(units) if key is None else sum(len(u.get(key, [])) for u in units)
        if found != entry.get(what):
            raise DatasetError(f"{path}: holds {found} {what}, {where} records {entry.get(what)}")
    if len(_UNIT_COUNTS) > 1 << 16:
        _UNIT_COUNTS.clear()
    _UNIT_COUNTS[entry["records_sha256"]] = [
        (sum(int(s["samples"]) for s in u["shards"]), len(u["shards"]), len(u["episodes"])) for u in units]
    return doc


def _unit_counts(root: str, entry: dict, where: str) -> list[tuple[int, int, int]]:
    """(samples, shards, episodes) of each unit of a segment: from this process's earlier read of its
    records (checked then, and named by their sha256), or read now."""
    counts = _UNIT_COUNTS.get(entry.get("records_sha256"))
    if counts is None:
        read_segment_doc(root, entry, where)
        counts = _UNIT_COUNTS[entry["records_sha256"]]
    return counts


def segmented_records(root: str | os.PathLike, manifest: dict,
                      where: str = "the manifest") -> tuple[dict, list[dict]]:
    """(manifest with its shard list, episode records) of a segmented version, as format 3 stored them
    (any version: htdata/store/manifest.py `load_records`).

    Args:
        root: the dataset root (path or URL).
        manifest: the version's manifest as stored.
        where: the manifest, for messages.

    Returns:
        A copy of the manifest with "shards" (first_sample filled), and the episode records with
        first_sample and shard names.
    """
    shards, episodes, first_shard_sample, first_episode_sample = [], [], 0, 0
    for entry in manifest["segments"]:
        for unit in read_segment_doc(root, entry, where)["units"]:
            for shard in unit["shards"]:
                shards.append({**shard, "first_sample": first_shard_sample})
                first_shard_sample += int(shard["samples"])
            for record in unit["episodes"]:
                episodes.append({**record, "first_sample": first_episode_sample})
                first_episode_sample += int(record["num_frames"])
    return {**manifest, "shards": shards}, episodes


def _segment_rows(root: str, entry: dict, where: str) -> np.ndarray:
    """A segment's index rows, local to each unit, checked against its records."""
    path, data = _read_checked(root, entry, "index", where)
    rows = parse_index(data, path)
    if len(rows) != entry.get("samples"):
        raise DatasetError(f"{path}: holds {len(rows)} index rows, {where} records {entry.get('samples')}")
    held = sum(n for n, _, _ in _unit_counts(root, entry, where))
    if held != len(rows):
        raise DatasetError(f"{path}: {len(rows)} index rows, but its units' shards hold {held} samples")
    return rows


def segment_parts(root: str | os.PathLike, manifest: dict, where: str = "the manifest") -> list[Part]:
    """The parts of a segmented version, read straight from its segments (what a writer carries).

    Args:
        root: the dataset root (path or URL).
        manifest: the version's manifest as stored.
        where: the manifest, for messages.

    Returns:
        One Part per unit, in order; records without the fields `assemble` computes.
    """
    parts = []
    for entry in manifest["segments"]:
        doc = read_segment_doc(root, entry, where)
        rows = _segment_rows(os.fspath(root), entry, where)
        start = 0
        for unit in doc["units"]:
            n = sum(int(s["samples"]) for s in unit["shards"])
            records = [{k: v for k, v in r.items() if k not in COMPUTED_FIELDS} for r in unit["episodes"]]
            parts.append(Part(unit=int(unit["unit"]), shards=[dict(s) for s in unit["shards"]],
                              rows=np.array(rows[start:start + n]), episodes=records))
            start += n
    return parts


def _global_rows(root: str, entry: dict, where: str, shard_base: int, episode_base: int) -> tuple[np.ndarray, int, int]:
    """A segment's rows with global shard and episode columns; returns them and the next bases."""
    rows = np.array(_segment_rows(root, entry, where))
    counts = _unit_counts(root, entry, where)
    samples = [n for n, _, _ in counts]
    shards = np.cumsum([shard_base] + [k for _, k, _ in counts])
    episodes = np.cumsum([episode_base] + [e for _, _, e in counts])
    rows["shard"] += np.repeat(shards[:-1], samples).astype(rows["shard"].dtype)
    rows["episode"] += np.repeat(episodes[:-1], samples).astype(rows["episode"].dtype)
    return rows, int(shards[-1]), int(episodes[-1])


def _assemble_into(root: str, manifest: dict, where: str, out) -> str:
    """Write the global rows of every segment to `out` (a file or buffer); returns the sha256 of the .npy bytes."""
    n = int(manifest["counts"]["samples"])
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": np.lib.format.dtype_to_descr(INDEX_DTYPE), "fortran_order": False, "shape": (n,)})
    h = hashlib.sha256(header.getvalue())
    out.write(header.getvalue())
    shard_base = episode_base = 0
    for entry in manifest["segments"]:
        rows, shard_base, episode_base = _global_rows(root, entry, where, shard_base, episode_base)
        data = rows.tobytes()
        h.update(data)
        out.write(data)
    return h.hexdigest()


def check_segment_rows(root: str | os.PathLike, manifest: dict, where: str = "the manifest") -> None:
    """Read every segment's index rows and check them against their sha256 and records, whether or not an
    assembled index is cached (`htdata validate`: a cached index says nothing of the files since).

    Args:
        root: the dataset root (path or URL).
        manifest: the version's manifest as stored.
        where: the manifest, for messages.

    Raises:
        DatasetError: a segment's rows differ from what the manifest records.
        FileNotFoundError: a segment file is missing.
    """
    for entry in manifest["segments"]:
        _segment_rows(os.fspath(root), entry, where)


def load_segment_index(root: str | os.PathLike, manifest: dict, where: str = "the manifest") -> np.ndarray:
    """The global index of a segmented version (INDEX_DTYPE), checked against the manifest's index_sha256.

    Args:
        root: the dataset root (path or URL).
        manifest: the version's manifest as stored.
        where: the manifest, for messages.

    Returns:
        The rows: in memory, or memory-mapped from the local cache when the index is large.

    Raises:
        DatasetError: a segment or the assembled index does not match what the manifest records.
    """
    root = os.fspath(root)
    expected = manifest.get("index_sha256")
    held, counted = sum(int(e.get("samples", 0)) for e in manifest["segments"]), int(manifest["counts"]["samples"])
    if held != counted:
        raise DatasetError(f"{root}: index has {held} rows, manifest counts {counted} (the rows its segments hold)")
    size = counted * INDEX_DTYPE.itemsize
    if size < INDEX_CACHE_MIN_BYTES and not storage.is_url(root):     # a remote one is fetched once, cached
        buf = io.BytesIO()
        found = _assemble_into(root, manifest, where, buf)
        if found != expected:
            raise DatasetError(f"{root}: the index assembled from {where}'s segments has sha256 {found[:12]}, "
                               f"the manifest records {str(expected)[:12]}")
        return parse_index(buf.getvalue(), f"{root} ({where})")
    target = cache_dir() / "index" / str(expected) / INDEX_FILE
    if not target.is_file():
        with atomic_open(target) as out:    # concurrent readers each write a temp file; the rename is atomic
            found = _assemble_into(root, manifest, where, out)
            if found != expected:
                raise DatasetError(f"{root}: the index assembled from {where}'s segments has sha256 "
                                   f"{found[:12]}, the manifest records {str(expected)[:12]}")
    return load_index_file(str(target))


def version_shards(root: str | os.PathLike, manifest: dict) -> list[dict]:
    """The shard entries a version lists (name, sha256, bytes, samples), from its manifest or its segments.

    Args:
        root: the dataset root (path or URL).
        manifest: the version's manifest as stored.
    """
    if not segmented(manifest):
        return manifest["shards"]
    return [s for entry in manifest["segments"]
            for u in read_segment_doc(root, entry, "the manifest")["units"] for s in u["shards"]]

