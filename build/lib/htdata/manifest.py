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

import hashlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata import storage
from htdata.codec import encode_png_u8
from htdata.format import (CANONICAL_FILE, EPISODES_FILE, FORMAT, INDEX_DTYPE, INDEX_FILE, LAYOUTS_DIR,
                           LEGACY_INDEX_DTYPE, PARTS_FILE, READABLE_FORMAT_VERSIONS, REGIONS_FILE)
from htdata.fsutil import write_bytes_atomic
from htdata.resources import validate_json
from htdata.shardio import SampleRecord, ShardRecord

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


def _place(root: Path, stem: str, ext: str, data: bytes) -> str:
    """Write `data` as layouts/{stem}.{ext}, or layouts/{stem}-{sha12}.{ext} when that name holds other bytes.

    Files an earlier version lists are never rewritten: a changed layout
    document (or coverage) gets a content-addressed name of its own.
    """
    rel = f"{LAYOUTS_DIR}/{stem}.{ext}"
    path = root / rel
    if path.is_file() and path.read_bytes() != data:
        rel = f"{LAYOUTS_DIR}/{stem}-{hashlib.sha256(data).hexdigest()[:12]}.{ext}"
        path = root / rel
    if not path.is_file():
        write_bytes_atomic(path, data)
    return rel


def write_layout_files(root: str | os.PathLike, layouts: list[LayoutArtifact],
                       canonical: CanonicalArtifact) -> tuple[dict, dict]:
    """Write the layouts/ files of a version; returns the manifest's (layouts, canonical) entries."""
    root = Path(root)
    (root / LAYOUTS_DIR).mkdir(parents=True, exist_ok=True)
    canon_bytes = (json.dumps(canonical.document, indent=2, sort_keys=True) + "\n").encode()
    canonical_entry = {
        "file": _place(root, Path(CANONICAL_FILE).stem, "json", canon_bytes),
        "regions": _place(root, Path(REGIONS_FILE).stem, "png", encode_png_u8(canonical.region_map, "canonical region map")),
        "parts": _place(root, Path(PARTS_FILE).stem, "png", encode_png_u8(canonical.part_map, "canonical part map")),
        "sha256": hashlib.sha256(canon_bytes).hexdigest()}
    layout_entries = {}
    for lay in sorted(layouts, key=lambda x: x.layout_id):
        doc = (json.dumps(lay.document, indent=2, sort_keys=True) + "\n").encode()
        cov = np.asarray(lay.coverage)
        if cov.size and cov.max() > 1:
            raise ValueError(f"layout {lay.layout_id!r}: coverage must be 0/1")
        layout_entries[lay.layout_id] = {
            "file": _place(root, lay.layout_id, "json", doc),
            "coverage": _place(root, f"coverage_{lay.layout_id}", "png",
                               encode_png_u8(cov.astype(np.uint8), f"coverage of {lay.layout_id}")),
            "sha256": hashlib.sha256(doc).hexdigest(),
        }
    return layout_entries, canonical_entry


def commit_dataset(root: str | os.PathLike, units: list[UnitResult], layouts: list[LayoutArtifact],
                   canonical: CanonicalArtifact, codec: dict, sources: list[dict],
                   created: str | None = None, htdata_version: str | None = None,
                   command: str = "commit") -> dict:
    """Commit `units` as a new dataset version at `root` (the first, on a fresh directory). Returns its manifest.

    Shards must already sit in ROOT/shards (ShardWriter put them there); their
    sizes are checked against the records. The version holds exactly these
    units; writers that keep a parent's episodes (ingest's append, rm, trim)
    build their parts and call snapshot.commit_parts themselves.
    """
    from htdata.parts import part_from_unit
    from htdata.snapshot import commit_parts, current_snapshot

    build_index(units)   # the cross-unit checks, with their messages
    layout_entries, canonical_entry = write_layout_files(root, layouts, canonical)
    fields = {"sources": list(sources), "layouts": layout_entries, "canonical": canonical_entry, "codec": codec}
    parts = [part_from_unit(u) for u in sorted(units, key=lambda u: u.unit)]
    return commit_parts(root, parts, fields, current_snapshot(root), command, created=created,
                        htdata_version=htdata_version, splits=lambda eps, sha: {})


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
    if manifest.get("format") != FORMAT or manifest.get("format_version") not in READABLE_FORMAT_VERSIONS:
        raise ValueError(f"{where}: format {manifest.get('format')!r} v{manifest.get('format_version')!r}, "
                         f"expected {FORMAT!r} v{' or v'.join(map(str, READABLE_FORMAT_VERSIONS))}")
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
    """Episode records of `manifest`'s version (the current version's when None)."""
    manifest = manifest if manifest is not None else load_manifest(root, validate=False)
    path = storage.join(root, manifest.get("episodes_file", EPISODES_FILE))
    return parse_episodes(storage.read_text(path), path)


class IndexDtypeError(ValueError):
    """index.npy is readable but its rows are not INDEX_DTYPE (`found`: their dtype)."""

    def __init__(self, where: str, found: np.dtype):
        super().__init__(f"{where}: index dtype {found} != {INDEX_DTYPE}")
        self.found = found


def _check_index_dtype(rows: np.ndarray, where: str) -> np.ndarray:
    """Rows as INDEX_DTYPE: a format 1/2 index (no raw columns) is converted in memory, sizes 0."""
    if rows.dtype == LEGACY_INDEX_DTYPE:
        converted = np.zeros(rows.shape, dtype=INDEX_DTYPE)
        for name in LEGACY_INDEX_DTYPE.names:
            converted[name] = rows[name]
        return converted
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
    """`manifest`'s index (the current version's when None) as INDEX_DTYPE; mmap for local datasets."""
    manifest = manifest if manifest is not None else load_manifest(root, validate=False)
    return load_index_file(storage.join(root, manifest.get("index_file", INDEX_FILE)), mmap)


def load_index_file(path: str, mmap: bool = True) -> np.ndarray:
    """An index.npy file (local path or URL) as INDEX_DTYPE; memory-mapped when local and `mmap`.

    A format 1/2 index is converted to INDEX_DTYPE in memory (not mapped); a
    new version of such a dataset writes its index in the current dtype.
    """
    local = storage.local_path(path)
    if local is None:
        return parse_index(storage.read_bytes(path), path)
    return _check_index_dtype(np.load(local, mmap_mode="r" if mmap else None, allow_pickle=False), path)
