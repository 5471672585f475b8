"""`htdata split` on a versioned dataset: commit split NAME as a new version, the other splits carried.

(Carrying splits to a child version is the store's: htdata/store/splitfiles.py.) An episode's part never changes because other episodes came or went: the new
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

from htdata.resources import validate_json
from htdata.store.splitfiles import PARTS, assignment_of, carried_splits, parent_split_docs
from htdata.store.splitrule import SplitError, build_split
from htdata.write.newversion import NewVersion


@dataclass
class SplitResult:
    """What `htdata split` wrote: the document, where, and how each part changed against the parent."""
    doc: dict
    path: Path
    version: int | None
    gained: dict[str, list[str]] = field(default_factory=dict)
    lost: dict[str, list[str]] = field(default_factory=dict)
    changed: bool = True      # False: the split would be identical, nothing was committed


def _carried_news(doc: dict) -> bool:
    """True when a carried split has something to say (episodes that left their part, or unassigned ones):
    re-making it then commits. Carried unchanged (another split was committed) it has nothing to say."""
    carried = doc.get("carried") or {}
    return bool(carried.get("left") or carried.get("unassigned"))


def kept_parts(previous: dict, episodes: list[dict]) -> dict[str, str]:
    """The parts `previous` gave the surviving `episodes`: an update keeps them (splitrule.assign_episodes)."""
    ids = {e["episode_id"] for e in episodes}
    return {e: p for e, p in assignment_of(previous).items() if e in ids}


def write_versioned_split(root, config, command: str) -> SplitResult:
    """Split a versioned dataset: a new version whose split NAME is (re)computed, the rest carried.

    An existing split NAME with the same params is UPDATED: its episodes keep
    their parts, new episodes are assigned by the rule. Other params need
    --force (config.force) and recompute it; the old one stays in its version.
    """
    root = Path(root)
    name = config.resolved_name()
    with NewVersion(root, command, new_units=False) as nv:   # the parent's parts, as they are
        snap = nv.parent
        previous = parent_split_docs(snap).get(name)
        sha = snap.manifest["episodes_sha256"]
        doc = build_split(snap.episodes, config, episodes_sha256=sha)
        if previous is not None and previous["params"] != doc["params"]:
            if not config.force:
                raise SplitError(f"split {name!r} exists with other params {previous['params']}; pass --force "
                                 f"to recompute it (version {snap.version} keeps the old one) or choose another --name")
        elif previous is not None:    # an update: its episodes keep their parts, new ones fill each task's share
            doc = build_split(snap.episodes, config, episodes_sha256=sha, fixed=kept_parts(previous, snap.episodes))
            ids = {e["episode_id"] for e in snap.episodes}
            doc["corrections"] = [c for c in previous["corrections"] if c["episode_id"] in ids]
            if (assignment_of(doc) == assignment_of(previous) and not _carried_news(previous)
                    and previous.get("episodes_sha256") == doc["episodes_sha256"]):
                # nothing to change: no new version (re-running `htdata split` is idempotent, also after
                # another split's commit carried this one unchanged into the current version)
                return SplitResult(doc=previous, path=root / snap.manifest["splits"][name]["file"],
                                   version=snap.version, gained={p: [] for p in PARTS},
                                   lost={p: [] for p in PARTS}, changed=False)
        validate_json(doc, "split", where=f"split {name!r}")
        data = (json.dumps(doc, indent=2) + "\n").encode()

        def splits(episodes, sha):
            return {**carried_splits(snap, episodes, sha), name: data}

        manifest = nv.commit(snap.parts(), splits=splits)
    old, new = assignment_of(previous) if previous else {}, assignment_of(doc)
    gained = {p: sorted(e for e, q in new.items() if q == p and old.get(e) != p) for p in PARTS}
    lost = {p: sorted(e for e, q in old.items() if q == p and new.get(e) != p) for p in PARTS}
    return SplitResult(doc=doc, path=root / manifest["splits"][name]["file"], version=manifest["version"],
                       gained=gained, lost=lost)
