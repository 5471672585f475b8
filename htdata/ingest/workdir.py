"""The output directory while an ingest runs: ownership check, unit records, leftovers.

Crash safety and resume: a finished unit writes DATASET/.work/unit-UUUUUU.json
atomically (its records, its fingerprint = pipeline + episode ids + input
fingerprints, its shards' sha256, its index rows as one array, the sha256
of the source files it hashed). A re-run skips units whose record,
fingerprint and shards (sha256) all match and that recorded no machine failure
(a full disk, an I/O error: "retry" in the failure), removes temp files and rewrites
every other unit from scratch. Units of a run are numbered from the current
version's `next_unit`: shards of committed versions are never touched, and
the current version stays current (and readable) until the new one is
committed, so a crashed or failed run damages nothing.
"""

from __future__ import annotations

import base64
import binascii
import json
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.format.table import INDEX_DTYPE, MANIFEST_FILE, SHARDS_DIR, WORK_DIR
from htdata.store.fsutil import sha256_file
from htdata.store.lock import is_lock_file
from htdata.store.manifest import load_manifest
from htdata.store.segments import version_shards
from htdata.store.versions import list_versions

# Keys a unit record must hold to be reused (records of older versions lack some: their units re-run).
RECORD_KEYS = ("unit", "fingerprint", "shards", "rows", "rows_dtype", "frames", "episodes", "failures", "dropped",
               "layouts", "source_sha256", "source_unreadable")
ROWS_DTYPE = str(INDEX_DTYPE.descr)      # what a record's "rows" are, as its "rows_dtype" says


def dumps(obj, compact: bool = False) -> bytes:
    """JSON bytes. `compact` for unit records; otherwise (reports people read) one top-level key a line,
    each value written by json's C encoder: an indented dump runs the pure-Python encoder, ~1 ms per
    episode of a large ingest's report (written twice per run, in the driver)."""
    if compact:
        return (json.dumps(obj, sort_keys=True, separators=(",", ":")) + "\n").encode()
    if not isinstance(obj, dict) or not obj:
        return (json.dumps(obj, sort_keys=True) + "\n").encode()
    lines = [f" {json.dumps(str(k))}: {json.dumps(v, sort_keys=True)}" for k, v in sorted(obj.items())]
    return ("{\n" + ",\n".join(lines) + "\n}\n").encode()


def encode_rows(rows: np.ndarray) -> str:
    """A unit's index rows (INDEX_DTYPE) as one string of its record: the raw bytes in base64 (one C call
    each way, ~75 characters a sample, where a JSON object per sample cost the driver a Python object per
    frame); the record names the dtype (`ROWS_DTYPE`), so a record of another format re-runs its unit."""
    return base64.b64encode(np.ascontiguousarray(rows, dtype=INDEX_DTYPE).tobytes()).decode("ascii")


def decode_rows(text: str, where: str) -> np.ndarray:
    """The index rows `encode_rows` made (DatasetError naming `where` if they do not decode)."""
    try:
        data = base64.b64decode(text.encode("ascii"), validate=True)
    except (binascii.Error, ValueError, AttributeError) as exc:
        raise DatasetError(f"{where}: index rows are not base64 ({exc})") from exc
    if len(data) % INDEX_DTYPE.itemsize:
        raise DatasetError(f"{where}: {len(data)} bytes of index rows are not whole {INDEX_DTYPE.itemsize}-byte rows")
    return np.frombuffer(data, INDEX_DTYPE).copy()


def unit_record_path(out: Path, unit: int) -> Path:
    return out / WORK_DIR / f"unit-{unit:06d}.json"


def spool_path(out: Path, unit: int) -> Path:
    return out / WORK_DIR / f"spool-{unit:06d}.bin"


def clear_unit_files(out: Path, unit: int) -> None:
    """Remove everything a (crashed or stale) run of this unit left behind."""
    unit_record_path(out, unit).unlink(missing_ok=True)
    for p in (out / SHARDS_DIR).glob(f"shard-{unit:06d}-*.tar"):
        p.unlink()
    for p in (out / SHARDS_DIR).glob(f".shard-{unit:06d}-*.tar.tmp"):
        p.unlink()
    spool_path(out, unit).unlink(missing_ok=True)


def load_valid_record(task) -> dict | None:
    """The unit's done record if it matches the task (a UnitTask) and its shards are intact, else None."""
    out = Path(task.out)
    path = unit_record_path(out, task.unit)
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if not all(k in record for k in RECORD_KEYS) or record["fingerprint"] != task.fingerprint() \
            or record["rows_dtype"] != ROWS_DTYPE:
        return None
    try:
        if len(decode_rows(record["rows"], str(path))) != record["frames"]:
            return None
    except DatasetError:
        return None
    if any(f.get("retry") for f in record["failures"]):   # a full disk, an I/O error: run it again
        return None
    for s in record["shards"]:
        p = out / SHARDS_DIR / s["name"]
        if not p.is_file() or p.stat().st_size != s["bytes"] or sha256_file(p) != s["sha256"]:
            return None
    return record


def check_output(out: Path) -> None:
    """Refuse a non-empty directory that is neither an htdata dataset nor an interrupted first ingest
    (a writer's lock file alone does not count: the lock then names that writer)."""
    if out.exists() and not out.is_dir():
        raise ArgumentError(f"{out}: exists and is not a directory")
    content = [p for p in out.iterdir() if not is_lock_file(p.name)] if out.is_dir() else []
    if content and not (out / MANIFEST_FILE).is_file() and not (out / WORK_DIR).is_dir() \
            and not list_versions(out):     # committed version files make it a dataset, pointer or not
        raise ArgumentError(f"{out}: directory is not empty and is not an htdata dataset; "
                            f"refusing to write into it (choose an empty or new directory)")


def prepare_output(out: Path) -> None:
    """The work and shard folders (the caller checked the directory and holds its lock)."""
    (out / WORK_DIR).mkdir(parents=True, exist_ok=True)
    (out / SHARDS_DIR).mkdir(parents=True, exist_ok=True)


def remove_empty_output(out: Path, subfolders: bool = True) -> None:
    """Remove the empty work and shard folders `prepare_output` made (the caller holds the lock) when they
    are all `out` holds, then `out` when it is empty: what a first ingest that failed before writing
    anything leaves. Anything a run wrote (a report naming its failures, a unit to resume) keeps it all."""
    skeleton = (out / WORK_DIR, out / SHARDS_DIR) if subfolders else ()
    try:
        content = [p for p in out.iterdir() if not is_lock_file(p.name)] if out.is_dir() and not out.is_symlink() else []
        if all(p in skeleton and p.is_dir() and not p.is_symlink() and not any(p.iterdir()) for p in content):
            for p in content:
                p.rmdir()
            if not subfolders:
                out.rmdir()
    except OSError:
        pass     # not ours to force: an error is already on its way


def committed_shards(out: Path) -> set[str]:
    """Every shard name some committed version file lists (what no cleanup may ever delete)."""

    names: set[str] = set()
    for v in list_versions(out):
        names |= {s["name"] for s in version_shards(out, load_manifest(out, validate=False, version=v))}
    return names


def remove_strays(out: Path, tasks: list, first_unit: int) -> None:
    """Temp files, spools, and uncommitted shards/records (units >= first_unit) outside the plan.

    Units >= first_unit (the current version's next_unit) belong to no committed version; a shard a
    version file lists is never deleted here all the same (checked against every version file).
    """
    planned = {t.unit for t in tasks}
    for p in list(out.rglob(".*.tmp")) + list((out / WORK_DIR).glob("spool-*.bin")):
        if not is_lock_file(p.name):   # a lock temp file belongs to a writer trying the lock now
            p.unlink(missing_ok=True)
    keep = committed_shards(out)
    for p in (out / SHARDS_DIR).glob("shard-*.tar"):
        unit = int(p.name.split("-")[1])
        if unit >= first_unit and unit not in planned and p.name not in keep:
            p.unlink()
    for p in (out / WORK_DIR).glob("unit-*.json"):
        if int(p.stem.split("-")[1]) not in planned:
            p.unlink()
