"""Splits under change: carry a parent version's splits into a new version, update one in place of none.

An episode's part never changes because other episodes came or went: the new
version's split NAME keeps every surviving episode in the part it had,
removed episodes leave their part, and counts/ratios are recomputed. New
episodes (an append) are in no part until `htdata split` assigns them by
the split's rule; `htdata validate --split` reports them as unassigned.
A carried split (format_version 2) records the episode file it describes
(`episodes_sha256`, instead of v1's manifest_sha256: a version's manifest
lists its splits' hashes, so a split cannot hold its manifest's hash) and
"carried": the version it came from, the episodes that left, the unassigned.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from htdata import storage
from htdata.versions import split_file

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
        from htdata.split import list_splits

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


@dataclass
class SplitResult:
    """What `htdata split` wrote: the document, where, and how each part changed against the parent."""
    doc: dict
    path: Path
    version: int | None
    gained: dict[str, list[str]] = field(default_factory=dict)
    lost: dict[str, list[str]] = field(default_factory=dict)


def keep_parts(previous: dict, fresh: dict, episodes: list[dict]) -> dict:
    """`fresh` (the rule applied to every episode) with every episode `previous` placed kept in its part.

    Only episodes new to the split take the rule's part, so no episode moves
    because others were appended. The rule's corrections that would move an
    old episode are dropped; the previous corrections of surviving episodes stay.
    """
    old = assignment_of(previous)
    ids = {e["episode_id"] for e in episodes}
    assignment = {**assignment_of(fresh), **{e: p for e, p in old.items() if e in ids}}
    parts, tasks, ratios = count_parts(assignment, episodes)
    corrections = [c for c in previous["corrections"] if c["episode_id"] in ids]
    corrections += [c for c in fresh["corrections"] if c["episode_id"] not in old]
    return {**fresh, "parts": parts, "tasks": tasks, "ratios": ratios, "corrections": corrections}


def write_versioned_split(root, config, command: str) -> SplitResult:
    """Split a versioned dataset: a new version whose split NAME is (re)computed, the rest carried.

    An existing split NAME with the same params is UPDATED: its episodes keep
    their parts, new episodes are assigned by the rule. Other params need
    --force (config.force) and recompute it; the old one stays in its version.
    """
    from htdata.lock import WriterLock
    from htdata.resources import validate_json
    from htdata.snapshot import commit_parts, open_snapshot
    from htdata.split import SplitError, build_split

    root = Path(root)
    name = config.resolved_name()
    with WriterLock(root, command):
        snap = open_snapshot(root)
        previous = parent_split_docs(snap).get(name)
        doc = build_split(snap.episodes, config, episodes_sha256=snap.manifest["episodes_sha256"])
        if previous is not None and previous["params"] != doc["params"]:
            if not config.force:
                raise SplitError(f"split {name!r} exists with other params {previous['params']}; pass --force "
                                 f"to recompute it (version {snap.version} keeps the old one) or choose another --name")
        elif previous is not None:
            doc = keep_parts(previous, doc, snap.episodes)
            if (assignment_of(doc) == assignment_of(previous) and not previous.get("carried")
                    and previous.get("episodes_sha256") == doc["episodes_sha256"]):
                # nothing to change: no new version (re-running `htdata split` is idempotent)
                return SplitResult(doc=previous, path=root / snap.manifest["splits"][name]["file"],
                                   version=snap.version, gained={p: [] for p in PARTS},
                                   lost={p: [] for p in PARTS})
        validate_json(doc, "split", where=f"split {name!r}")
        data = (json.dumps(doc, indent=2) + "\n").encode()

        def splits(episodes, sha):
            return {**carried_splits(snap, episodes, sha), name: data}

        manifest = commit_parts(root, snap.parts(), {}, snap, command, splits=splits)
    old, new = assignment_of(previous) if previous else {}, assignment_of(doc)
    gained = {p: sorted(e for e, q in new.items() if q == p and old.get(e) != p) for p in PARTS}
    lost = {p: sorted(e for e, q in old.items() if q == p and new.get(e) != p) for p in PARTS}
    return SplitResult(doc=doc, path=root / manifest["splits"][name]["file"], version=manifest["version"],
                       gained=gained, lost=lost)
