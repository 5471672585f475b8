"""Dataset manifest, episode records and sample index: the records of a work unit, the layout files, the loaders.

A version is committed by htdata/store/snapshot.py (`commit_parts`) from the
parts of its work units (`UnitResult` -> htdata/store/parts.py); dataset.json
is written LAST through tmp + fsync + rename, so a dataset either has a
complete manifest or none: readers treat a missing dataset.json as "not committed".

`load_manifest` / `load_records` (`load_episodes`) / `load_index` (and `parse_episodes`,
htdata/store/indexfile.py's `parse_index`, for callers that hash the bytes they parse) are THE
loaders of a version, whatever its format: a format 4 version's records come from its segments
(htdata/store/segments.py), a format 1-3 one's from its episodes.jsonl and index.npy. The reader,
split, validate and preview all go through them.
File names, the index dtype and the member table live in htdata/format/table.py.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import DatasetError
from htdata.fileio import write_bytes_atomic
from htdata.format.codec import encode_png_u8
from htdata.format.shardio import SampleRecord, ShardRecord
from htdata.format.table import (
    CANONICAL_FILE,
    EPISODES_FILE,
    FORMAT,
    INDEX_FILE,
    LAYOUTS_DIR,
    MANIFEST_FILE,
    PARTS_FILE,
    READABLE_FORMAT_VERSIONS,
    REGIONS_FILE,
)
from htdata.resources import validate_json
from htdata.store import storage
from htdata.store.confine import check_manifest_paths, inside
from htdata.store.indexfile import load_index_file
from htdata.store.segments import load_segment_index, segmented, segmented_records
from htdata.store.versions import DatasetStateError, manifest_path


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


# -- loading ---------------------------------------------------------------

def load_manifest(root: str | os.PathLike, validate: bool = True, version: int | None = None) -> dict:
    """The current version's manifest (dataset.json), or version `version`'s (versions/vN.json)."""
    path = manifest_path(root, version)
    if not storage.exists(path):
        raise FileNotFoundError(f"{path}: no manifest: not a committed htdata dataset")
    try:
        return parse_manifest(storage.read_text(path), path, validate)
    except json.JSONDecodeError as exc:   # a damaged file: name it and the way out
        raise DatasetStateError(f"{path}: not valid JSON ({exc}); if {MANIFEST_FILE} is intact and names this "
                                f"version, `htdata repair {root}` restores it") from None


def parse_manifest(data: str | bytes, where: str, validate: bool = True) -> dict:
    """dataset.json text/bytes -> manifest (for callers that hash the bytes they parse).

    Invalid JSON raises json.JSONDecodeError; another format or a schema error, ValueError naming `where`.
    """
    manifest = json.loads(data)
    if not isinstance(manifest, dict):
        raise DatasetError(f"{where}: a manifest is a JSON object, found {type(manifest).__name__}")
    if manifest.get("format") != FORMAT or manifest.get("format_version") not in READABLE_FORMAT_VERSIONS:
        raise DatasetError(f"{where}: format {manifest.get('format')!r} v{manifest.get('format_version')!r}, "
                           f"expected {FORMAT!r} v{' or v'.join(map(str, READABLE_FORMAT_VERSIONS))}")
    if validate:
        validate_json(manifest, "manifest", where=str(where), error=DatasetError)
    check_manifest_paths(manifest, str(where))   # always: a stranger's dataset never names files outside its root
    return manifest


def parse_episodes(text: str, where: str) -> list[dict]:
    """episodes.jsonl text -> records; a bad line is an error naming `where` and the line."""
    episodes = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                episodes.append(json.loads(line))
            except json.JSONDecodeError as e:
                raise DatasetError(f"{where}:{lineno}: invalid JSON: {e}") from None
    return episodes


def load_episodes(root: str | os.PathLike, manifest: dict | None = None) -> list[dict]:
    """Episode records of `manifest`'s version (the current version's when None), each with first_sample and
    shard names: a format 4 version's from its segments, a format 1-3 one's from its episodes.jsonl."""
    return load_records(root, manifest)[1]


def load_records(root: str | os.PathLike, manifest: dict | None = None) -> tuple[dict, list[dict]]:
    """(manifest as a reader sees it, episode records) of any version: a format 4 manifest with the shard list
    its segments hold (htdata/store/segments.py), a format 1-3 one as it is.

    Args:
        root: the dataset root (path or URL).
        manifest: the version's manifest as stored (None: the current version's).
    """
    manifest = manifest if manifest is not None else load_manifest(root, validate=False)
    if segmented(manifest):
        return segmented_records(root, manifest)
    path = inside(root, manifest.get("episodes_file", EPISODES_FILE), "episodes_file")
    return manifest, parse_episodes(storage.read_text(path), path)


def load_index(root: str | os.PathLike, mmap: bool = True, manifest: dict | None = None) -> np.ndarray:
    """`manifest`'s index (the current version's when None) as INDEX_DTYPE: a format 4 version's assembled from
    its segments (a large one mapped from the local cache), a format 1-3 one's index.npy (mmap when local and
    `mmap`; a remote one is read whole: DatasetMetadata caches it, htdata/store/remote.py)."""
    manifest = manifest if manifest is not None else load_manifest(root, validate=False)
    if segmented(manifest):
        return load_segment_index(root, manifest)
    return load_index_file(inside(root, manifest.get("index_file", INDEX_FILE), "index_file"), mmap)
