"""Dataset manifest, episode records and sample index: build, commit, load.

`commit_dataset` turns the results of the work units (their shards, sample
records and episode records) into the three files of DESIGN.md "Dataset on
disk": episodes.jsonl, index.npy and dataset.json. dataset.json is written
LAST through tmp + fsync + rename, so a dataset either has a complete
manifest or none: readers treat a missing dataset.json as "not committed".

`load_manifest` / `load_episodes` / `load_index` (and `parse_episodes` /
`parse_index` for callers that hash the bytes they parse) are THE loaders of
those files: the reader, split, validate and preview all go through them.
File names, the index dtype and the member table live in htdata/format.py.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata import storage
from htdata.codec import encode_png_u8
from htdata.format import (CANONICAL_FILE, EPISODES_FILE, FORMAT, FORMAT_VERSION, HANDS, INDEX_DTYPE, INDEX_FILE,
                           LAYOUTS_DIR, MANIFEST_FILE, PARTS_FILE, REGIONS_FILE, SHARDS_DIR, SIZE_FIELDS,
                           tactile_member)
from htdata.fsutil import write_bytes_atomic
from htdata.resources import validate_json
from htdata.shardio import SampleRecord, ShardRecord, parse_key

@dataclass
class UnitResult:
    """What one ingest work unit produced.

    `samples[i].shard` indexes `shards`; `episodes` are episode records
    (schemas/episode.schema.json) without `first_sample`/`shards`, which the
    commit fills in. Each episode's samples are contiguous, frames 0..n-1.
    """
    unit: int
    shards: list[ShardRecord]
    samples: list[SampleRecord]
    episodes: list[dict]


@dataclass
class LayoutArtifact:
    """A glove layout to copy into DATASET/layouts: its JSON document and coverage."""
    layout_id: str
    document: dict
    coverage: np.ndarray  # (224,224) uint8 0/1


@dataclass
class CanonicalArtifact:
    """The canonical hand template: JSON document, region ids and part ids maps."""
    document: dict
    region_map: np.ndarray  # (224,224) uint8 region ids
    part_map: np.ndarray    # (224,224) uint8 part ids


@dataclass
class BuiltIndex:
    rows: np.ndarray              # INDEX_DTYPE
    episodes: list[dict]
    shards: list[dict]            # manifest shard entries




def build_index(units: list[UnitResult]) -> BuiltIndex:
    """Concatenate units (sorted by unit number) into global rows/episodes/shards (htdata/parts.py)."""
    from htdata.parts import assemble, part_from_unit

    units = sorted(units, key=lambda u: u.unit)
    seen_units = [u.unit for u in units]
    if len(set(seen_units)) != len(seen_units):
        raise ValueError(f"duplicate work unit numbers in commit: {seen_units}")
    owner: dict[str, int] = {}
    for u in units:
        for rec in u.episodes:
            if owner.setdefault(rec["episode_id"], u.unit) != u.unit:
                raise ValueError(f"unit {u.unit}: episode {rec['episode_id']!r} appears twice in the dataset "
                                 f"(also in unit {owner[rec['episode_id']]})")
    built = assemble([part_from_unit(u) for u in units])
    return BuiltIndex(rows=built.rows, episodes=built.episodes, shards=built.shards)


def _frames_per_hand(rows: np.ndarray) -> dict[str, int]:
    return {hand: int(np.count_nonzero(rows[SIZE_FIELDS[tactile_member(hand)]])) for hand in HANDS}


def commit_dataset(root: str | os.PathLike, units: list[UnitResult], layouts: list[LayoutArtifact],
                   canonical: CanonicalArtifact, codec: dict, sources: list[dict],
                   created: str | None = None, htdata_version: str | None = None) -> dict:
    """Write layouts/, episodes.jsonl, index.npy and finally dataset.json. Returns the manifest.

    Shards must already sit in ROOT/shards (ShardWriter put them there); their
    sizes are checked against the records. sha256 of shards come from the
    writer (computed while writing), of the other files from disk.
    """
    root = Path(root)
    built = build_index(units)
    for entry in built.shards:
        path = root / SHARDS_DIR / entry["name"]
        if not path.is_file():
            raise FileNotFoundError(f"{path}: shard listed by a work unit is missing")
        if path.stat().st_size != entry["bytes"]:
            raise ValueError(f"{path}: size {path.stat().st_size} != recorded {entry['bytes']}")
    for ep in built.episodes:
        validate_json(ep, "episode", where=f"{EPISODES_FILE}: episode {ep.get('episode_id')!r}")
        for hand, layout_id in ep["layouts"].items():
            if layout_id not in {lay.layout_id for lay in layouts}:
                raise ValueError(f"episode {ep['episode_id']!r}: layout {layout_id!r} ({hand}) not provided to commit")

    layout_dir = root / LAYOUTS_DIR
    layout_dir.mkdir(parents=True, exist_ok=True)
    canon_bytes = (json.dumps(canonical.document, indent=2, sort_keys=True) + "\n").encode()
    write_bytes_atomic(layout_dir / CANONICAL_FILE, canon_bytes)
    write_bytes_atomic(layout_dir / REGIONS_FILE, encode_png_u8(canonical.region_map, "canonical region map"))
    write_bytes_atomic(layout_dir / PARTS_FILE, encode_png_u8(canonical.part_map, "canonical part map"))
    layout_entries = {}
    for lay in sorted(layouts, key=lambda x: x.layout_id):
        doc = (json.dumps(lay.document, indent=2, sort_keys=True) + "\n").encode()
        cov = np.asarray(lay.coverage)
        if cov.size and cov.max() > 1:
            raise ValueError(f"layout {lay.layout_id!r}: coverage must be 0/1")
        write_bytes_atomic(layout_dir / f"{lay.layout_id}.json", doc)
        write_bytes_atomic(layout_dir / f"coverage_{lay.layout_id}.png",
                      encode_png_u8(cov.astype(np.uint8), f"coverage of {lay.layout_id}"))
        layout_entries[lay.layout_id] = {
            "file": f"{LAYOUTS_DIR}/{lay.layout_id}.json",
            "coverage": f"{LAYOUTS_DIR}/coverage_{lay.layout_id}.png",
            "sha256": hashlib.sha256(doc).hexdigest(),
        }

    episodes_bytes = "".join(json.dumps(ep, sort_keys=True) + "\n" for ep in built.episodes).encode()
    write_bytes_atomic(root / EPISODES_FILE, episodes_bytes)
    buf = io.BytesIO()
    np.save(buf, built.rows, allow_pickle=False)
    index_bytes = buf.getvalue()
    write_bytes_atomic(root / INDEX_FILE, index_bytes)

    from htdata import __version__

    manifest = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "created": created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "htdata_version": htdata_version or __version__,
        "sources": list(sources),
        "layouts": layout_entries,
        "canonical": {"file": f"{LAYOUTS_DIR}/{CANONICAL_FILE}", "regions": f"{LAYOUTS_DIR}/{REGIONS_FILE}",
                      "parts": f"{LAYOUTS_DIR}/{PARTS_FILE}", "sha256": hashlib.sha256(canon_bytes).hexdigest()},
        "codec": codec,
        "tasks": sorted({ep["task"] for ep in built.episodes}),
        "scenes": sorted({ep["scene"] for ep in built.episodes}),
        "counts": {"episodes": len(built.episodes), "samples": int(len(built.rows)),
                   "shards": len(built.shards), "frames_per_hand": _frames_per_hand(built.rows)},
        "shards": built.shards,
        "episodes_file": EPISODES_FILE,
        "episodes_sha256": hashlib.sha256(episodes_bytes).hexdigest(),
        "index_file": INDEX_FILE,
        "index_sha256": hashlib.sha256(index_bytes).hexdigest(),
    }
    validate_json(manifest, "manifest", where=f"{root / MANIFEST_FILE}")
    write_bytes_atomic(root / MANIFEST_FILE, (json.dumps(manifest, indent=2) + "\n").encode())
    return manifest


# -- loading ---------------------------------------------------------------

def load_manifest(root: str | os.PathLike, validate: bool = True, version: int | None = None) -> dict:
    """The current version's manifest (dataset.json), or version `version`'s (versions/vN.json)."""
    from htdata.versions import manifest_path

    path = manifest_path(root, version)
    if not storage.exists(path):
        raise FileNotFoundError(f"{path}: no manifest: not a committed htdata dataset")
    return parse_manifest(storage.read_text(path), path, validate)


def parse_manifest(data: str | bytes, where: str, validate: bool = True) -> dict:
    """dataset.json text/bytes -> manifest (for callers that hash the bytes they parse).

    Invalid JSON raises json.JSONDecodeError; another format or a schema error, ValueError naming `where`.
    """
    manifest = json.loads(data)
    if not isinstance(manifest, dict):
        raise ValueError(f"{where}: a manifest is a JSON object, found {type(manifest).__name__}")
    if manifest.get("format") != FORMAT or manifest.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{where}: format {manifest.get('format')!r} v{manifest.get('format_version')!r}, "
                         f"expected {FORMAT!r} v{FORMAT_VERSION}")
    if validate:
        validate_json(manifest, "manifest", where=str(where))
    return manifest


def parse_episodes(text: str, where: str) -> list[dict]:
    """episodes.jsonl text -> records; a bad line is an error naming `where` and the line."""
    episodes = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                episodes.append(json.loads(line))
            except json.JSONDecodeError as e:
                raise ValueError(f"{where}:{lineno}: invalid JSON: {e}") from None
    return episodes


def load_episodes(root: str | os.PathLike, manifest: dict | None = None) -> list[dict]:
    """Episode records of `manifest`'s version (its "episodes_file"; episodes.jsonl without one)."""
    path = storage.join(root, (manifest or {}).get("episodes_file", EPISODES_FILE))
    return parse_episodes(storage.read_text(path), path)


class IndexDtypeError(ValueError):
    """index.npy is readable but its rows are not INDEX_DTYPE (`found`: their dtype)."""

    def __init__(self, where: str, found: np.dtype):
        super().__init__(f"{where}: index dtype {found} != {INDEX_DTYPE}")
        self.found = found


def _check_index_dtype(rows: np.ndarray, where: str) -> np.ndarray:
    if rows.dtype != INDEX_DTYPE:
        raise IndexDtypeError(where, rows.dtype)
    return rows


def parse_index(data: bytes, where: str) -> np.ndarray:
    """index.npy bytes -> rows (for callers that hash the bytes they parse)."""
    try:
        rows = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as e:
        raise ValueError(f"{where}: unreadable index: {e}") from None
    return _check_index_dtype(rows, where)


def load_index(root: str | os.PathLike, mmap: bool = True, manifest: dict | None = None) -> np.ndarray:
    """`manifest`'s index (its "index_file"; index.npy without one) as INDEX_DTYPE; mmap for local datasets."""
    path = storage.join(root, (manifest or {}).get("index_file", INDEX_FILE))
    local = storage.local_path(path)
    if local is None:
        return parse_index(storage.read_bytes(path), path)
    return _check_index_dtype(np.load(local, mmap_mode="r" if mmap else None, allow_pickle=False), path)
