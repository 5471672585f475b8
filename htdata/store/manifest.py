"""Dataset manifest, episode records and sample index: the records of a work unit, the layout files, the loaders.

A version is committed by htdata/store/snapshot.py (`commit_parts`) from the
parts of its work units (`UnitResult` -> htdata/store/parts.py); dataset.json
is written LAST through tmp + fsync + rename, so a dataset either has a
complete manifest or none: readers treat a missing dataset.json as "not committed".

`load_manifest` / `load_episodes` / `load_index` (and `parse_episodes` /
`parse_index` for callers that hash the bytes they parse) are THE loaders of
those files: the reader, split, validate and preview all go through them.
File names, the index dtype and the member table live in htdata/format/table.py.
"""

from __future__ import annotations

import hashlib
import io
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
    INDEX_DTYPE,
    INDEX_DTYPES,
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
    """Episode records of `manifest`'s version (the current version's when None)."""
    manifest = manifest if manifest is not None else load_manifest(root, validate=False)
    path = inside(root, manifest.get("episodes_file", EPISODES_FILE), "episodes_file")
    return parse_episodes(storage.read_text(path), path)


class IndexDtypeError(DatasetError):
    """index.npy is readable but its rows are not INDEX_DTYPE (`found`: their dtype)."""

    def __init__(self, where: str, found: np.dtype):
        super().__init__(f"{where}: index dtype {found} != {INDEX_DTYPE}")
        self.found = found


def _check_index_dtype(rows: np.ndarray, where: str) -> np.ndarray:
    """Rows as INDEX_DTYPE: an older format's index (fewer size columns) is converted in memory, sizes 0."""
    if rows.dtype == INDEX_DTYPE:
        return rows
    if rows.dtype not in INDEX_DTYPES.values():
        raise IndexDtypeError(where, rows.dtype)
    converted = np.zeros(rows.shape, dtype=INDEX_DTYPE)
    for name in rows.dtype.names:
        converted[name] = rows[name]
    return converted


def _check_index_header(f, size: int, where: str) -> None:
    """Refuse an index.npy whose header declares more rows than its bytes hold, before np.load maps or
    allocates them (a header declaring 1e11 rows was a bare mmap ValueError, or a 4 TB allocation)."""
    from numpy.lib import format as npy

    try:
        version = npy.read_magic(f)
        shape, _, dtype = (npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0)(f)
    except Exception as e:
        raise DatasetError(f"{where}: unreadable index header: {e}") from None
    rows = 1
    for d in shape:
        rows *= int(d)
    held = size - f.tell()
    if rows * dtype.itemsize > held:
        raise DatasetError(f"{where}: index header declares {rows} rows of {dtype.itemsize} bytes but the file "
                           f"holds {held} bytes of rows: damaged or forged index, refused")


def parse_index(data: bytes, where: str) -> np.ndarray:
    """index.npy bytes -> rows (for callers that hash the bytes they parse)."""
    _check_index_header(io.BytesIO(data), len(data), where)
    try:
        rows = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as e:
        raise DatasetError(f"{where}: unreadable index: {e}") from None
    return _check_index_dtype(rows, where)


def load_index(root: str | os.PathLike, mmap: bool = True, manifest: dict | None = None) -> np.ndarray:
    """`manifest`'s index (the current version's when None) as INDEX_DTYPE; mmap for local datasets."""
    manifest = manifest if manifest is not None else load_manifest(root, validate=False)
    return load_index_file(inside(root, manifest.get("index_file", INDEX_FILE), "index_file"), mmap)


def load_index_file(path: str, mmap: bool = True) -> np.ndarray:
    """An index.npy file (local path or URL) as INDEX_DTYPE; memory-mapped when local and `mmap`.

    A format 1/2 index is converted to INDEX_DTYPE in memory (not mapped); a
    new version of such a dataset writes its index in the current dtype.
    """
    local = storage.local_path(path)
    if local is None:
        return parse_index(storage.read_bytes(path), path)
    with open(local, "rb") as f:
        _check_index_header(f, os.fstat(f.fileno()).st_size, path)
    try:
        rows = np.load(local, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DatasetError(f"{path}: unreadable index: {e}") from None
    return _check_index_dtype(rows, path)
