"""The split documents of a version: where they live, what they count, how they carry to a child version.

Every writer of a new version (ingest's append, rm, trim, merge, split) carries
the parent's splits through `carried_splits`: an episode keeps its part, removed
episodes leave it, new ones are unassigned until `htdata split` assigns them
(htdata/curate/split.py holds the rule). A carried split (format_version 2)
records the episode file it describes (`episodes_sha256`) and "carried": the
version it came from, the episodes that left, the unassigned.
"""

from __future__ import annotations

import json
from pathlib import Path

from htdata.errors import HtdataError
from htdata.format.table import SPLITS_DIR
from htdata.store import storage
from htdata.store.versions import manifest_path, split_file

PARTS = ("train", "test", "ood")


def _fraction(num: int, den: int) -> float:
    return float(num) / den if den else 0.0


def count_parts(assignment: dict[str, str], episodes: list[dict],
                part_names: tuple[str, ...] = PARTS) -> tuple[dict, dict, dict]:
    """(parts, per-task counts, ratios) of a split document for episode records -> part.

    Episodes missing from `assignment` are counted nowhere (unassigned).
    `part_names`: train / test / ood for `htdata split`'s splits; a hand-made
    split may name others (counted, ratios over train / test / ood only).
    """
    part_names = tuple(dict.fromkeys((*part_names, *assignment.values())))
    parts = {p: {"episodes": [], "frames": 0} for p in part_names}
    tasks: dict[str, dict] = {}
    for ep in sorted(episodes, key=lambda e: e["episode_id"]):
        part = assignment.get(ep["episode_id"])
        if part is None:
            continue
        frames = int(ep["num_frames"])
        parts[part]["episodes"].append(ep["episode_id"])
        parts[part]["frames"] += frames
        counts = tasks.setdefault(ep["task"], {p: {"episodes": 0, "frames": 0} for p in part_names})
        counts[part]["episodes"] += 1
        counts[part]["frames"] += frames
    n = {p: len(parts[p]["episodes"]) if p in parts else 0 for p in PARTS}
    f = {p: parts[p]["frames"] if p in parts else 0 for p in PARTS}
    ratios = {
        "test_of_in_distribution": {"episodes": _fraction(n["test"], n["train"] + n["test"]),
                                    "frames": _fraction(f["test"], f["train"] + f["test"])},
        "ood_of_all": {"episodes": _fraction(n["ood"], sum(n.values())),
                       "frames": _fraction(f["ood"], sum(f.values()))},
    }
    return parts, dict(sorted(tasks.items())), ratios


def assignment_of(doc: dict) -> dict[str, str]:
    return {eid: part for part, entry in doc["parts"].items() for eid in entry["episodes"]}


def parent_split_docs(snap) -> dict[str, dict]:
    """The split documents of a snapshot's version (versioned: manifest "splits"; else splits/*.json)."""
    entries = snap.manifest.get("splits")
    if entries is None:    # a dataset from before versions: splits/NAME.json beside the manifest
        entries = {name: {"file": split_file(None, name)} for name in list_splits(snap.root, snap.manifest)}
    return {name: json.loads(storage.read_text(storage.join(snap.root, e["file"]))) for name, e in entries.items()}


def carry_split(doc: dict, episodes: list[dict], from_version: int | None, episodes_sha256: str) -> dict:
    """`doc` restricted to the surviving `episodes`, recounted; "carried" says what left / is unassigned."""
    old = assignment_of(doc)
    ids = {e["episode_id"] for e in episodes}
    gone = sorted(set(old) - ids)
    unassigned = sorted(ids - set(old))
    parts, tasks, ratios = count_parts({e: p for e, p in old.items() if e in ids}, episodes, tuple(doc["parts"]))
    out = {k: v for k, v in doc.items() if k != "manifest_sha256"}
    out.update({"format_version": 2, "parts": parts, "tasks": tasks, "ratios": ratios,
                "episodes_sha256": episodes_sha256})
    out["corrections"] = [c for c in doc.get("corrections", []) if c["episode_id"] in ids]
    out["carried"] = {"from_version": from_version, "left": gone, "unassigned": unassigned}
    return out


def carried_splits(snap, episodes: list[dict], episodes_sha256: str) -> dict[str, bytes]:
    """Split files (name -> bytes) of a new version made from `snap` holding `episodes`."""
    return {name: (json.dumps(carry_split(doc, episodes, snap.version, episodes_sha256), indent=2) + "\n").encode()
            for name, doc in parent_split_docs(snap).items()}


def _current_manifest(dataset) -> dict | None:
    try:
        return json.loads(Path(manifest_path(dataset, None)).read_bytes())
    except (OSError, ValueError):
        return None


def split_path(dataset, name: str, manifest: dict | None = None) -> Path:
    """Where split NAME of a dataset's version lives (the current one unless `manifest` is given).

    Versioned: versions/vN/splits/NAME.json (the manifest's "splits" entry);
    written before versions: DATASET/splits/NAME.json.
    """
    manifest = manifest if manifest is not None else _current_manifest(dataset)
    if manifest is not None and "version" in manifest:
        entry = manifest.get("splits", {}).get(name)
        return Path(dataset) / (entry["file"] if entry else split_file(manifest["version"], name))
    return Path(dataset) / SPLITS_DIR / f"{name}.json"


def list_splits(dataset, manifest: dict | None = None) -> list[str]:
    """Names of the splits of a dataset's version (the current one unless `manifest` is given), sorted."""
    manifest = manifest if manifest is not None else _current_manifest(dataset)
    if manifest is not None and "version" in manifest:
        return sorted(manifest.get("splits", {}))
    folder = Path(dataset) / SPLITS_DIR
    return sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []


class SplitRejected(HtdataError, ValueError):
    """A split whose file no longer matches its version's manifest, or whose parts overlap."""


def parse_split_doc(data: bytes, path: str, name: str) -> dict:
    """A split file's bytes -> its document, refused when not JSON, without parts, or when parts overlap."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise SplitRejected(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("parts"), dict):
        raise SplitRejected(f"{path}: split has no 'parts' object")
    seen: dict[str, str] = {}
    for part, body in sorted(doc["parts"].items()):
        for eid in body.get("episodes", []) if isinstance(body, dict) else []:
            if seen.setdefault(eid, part) != part:
                raise SplitRejected(f"{path}: episode {eid!r} is in both {seen[eid]} and {part}: the parts "
                                    f"overlap (train/test leakage); re-make it with `htdata split --name {name}`")
    return doc
