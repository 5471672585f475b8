"""The output directory while an ingest runs: ownership check, unit records, leftovers.

Crash safety and resume: a finished unit writes DATASET/.work/unit-UUUUUU.json
atomically (its records, its fingerprint = pipeline + episode ids + source
and layout fingerprints, its shards' sha256). A re-run skips units whose
record, fingerprint and shards (sha256) all match, removes temp files and
rewrites every other unit from scratch. dataset.json is removed at start and
written LAST by the commit, so a crashed run is never mistaken for a dataset.
"""

from __future__ import annotations

import json
from pathlib import Path

from htdata.format import MANIFEST_FILE, SHARDS_DIR, WORK_DIR
from htdata.fsutil import sha256_file, write_bytes_atomic

STATE_FILE = "ingest.json"          # under .work: which pipelines this directory belongs to
# Keys a unit record must hold to be reused (records of older versions lack some: their units re-run).
RECORD_KEYS = ("unit", "fingerprint", "shards", "samples", "episodes", "failures", "dropped", "layouts")


def dumps(obj) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode()


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
    if not all(k in record for k in RECORD_KEYS) or record["fingerprint"] != task.fingerprint():
        return None
    for s in record["shards"]:
        p = out / SHARDS_DIR / s["name"]
        if not p.is_file() or p.stat().st_size != s["bytes"] or sha256_file(p) != s["sha256"]:
            return None
    return record


def directory_identity(sources: list) -> dict:
    return {"pipelines": [s.pipeline.to_dict() for s in sources]}


def prepare_output(out: Path, identity: dict) -> None:
    """Refuse a non-empty directory that is not a previous ingest of the same pipeline(s)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()):
        state = out / WORK_DIR / STATE_FILE
        if not state.is_file():
            raise ValueError(f"{out}: directory is not empty and is not an htdata ingest output; "
                             f"refusing to write into it (choose an empty or new directory)")
        try:
            previous = json.loads(state.read_text())
        except json.JSONDecodeError:
            previous = None
        if previous != identity:
            names = [p["name"] for p in (previous or {}).get("pipelines", [])]
            raise ValueError(f"{out}: holds an ingest of different pipeline(s) {names} or different settings; "
                             f"refusing to mix datasets (use a new directory)")
    (out / WORK_DIR).mkdir(parents=True, exist_ok=True)
    (out / SHARDS_DIR).mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(out / WORK_DIR / STATE_FILE, dumps(identity))
    # Not committed while we work: a crash must not leave a manifest naming rewritten shards.
    (out / MANIFEST_FILE).unlink(missing_ok=True)


def remove_strays(out: Path, tasks: list) -> None:
    """Temp files, spools, and shards/records of unit numbers outside the plan."""
    planned = {t.unit for t in tasks}
    for p in list(out.rglob(".*.tmp")) + list((out / WORK_DIR).glob("spool-*.bin")):
        p.unlink()
    for p in (out / SHARDS_DIR).glob("shard-*.tar"):
        if int(p.name.split("-")[1]) not in planned:
            p.unlink()
    for p in (out / WORK_DIR).glob("unit-*.json"):
        if int(p.stem.split("-")[1]) not in planned:
            p.unlink()
