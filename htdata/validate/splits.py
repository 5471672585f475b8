"""Splits (`--split NAME`): the split file agrees with the dataset it claims to split.

The split's manifest hash is this dataset.json's; OOD tasks are absent from
train and test; parts are disjoint and cover every episode; the stated frame
counts and ratios equal what the parts hold; no byte-identical frame
(sha256 of the rgb + tactile member bytes, `frame_digest`, computed by the
shard workers) sits in two parts.
"""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from pathlib import Path

from htdata.errors import ArgumentError
from htdata.format.shardio import sample_key
from htdata.format.table import HANDS, MANIFEST_FILE, RGB_MEMBER, raw_member, tactile_member
from htdata.resources import validate_json
from htdata.store.splitfiles import PARTS, list_splits, split_path
from htdata.store.splitrule import test_counts
from htdata.validate.loaded import Loaded, load_dataset
from htdata.validate.report import Check

HASHED_MEMBERS = (RGB_MEMBER, *(tactile_member(hand) for hand in HANDS))
_RAW_OF = {tactile_member(hand): raw_member(hand) for hand in HANDS}


def frame_digest(members: dict[str, bytes]) -> str:
    """sha256 over a sample's rgb + tactile member bytes (absent members hash as empty).

    A hand whose map is not stored (htdata/format/mapstorage.py) hashes its raw rows, which the map is
    rendered from, in its place.
    """
    h = hashlib.sha256()
    for suffix in HASHED_MEMBERS:
        data = members.get(suffix)
        if data is None and suffix in _RAW_OF:
            data = members.get(_RAW_OF[suffix])
        h.update(suffix.encode() + b"\0" + (data or b""))
    return h.hexdigest()


def check_split_name(ds: Loaded, name: str) -> None:
    """ArgumentError (one line) when the version has no split `name`: a typo is said before validating."""
    known = list_splits(ds.root, ds.manifest)
    if name not in known:
        version = ds.manifest.get("version")
        raise ArgumentError(f"{ds.root}: {'version ' + str(version) if version else 'the dataset'} has no split "
                            f"{name!r} (its splits: {', '.join(known) or 'none'}); nothing validated")


def check_splits(ds: Loaded, name: str, hashes: dict[int, str], check: Check) -> dict | None:
    """Every split check; `hashes`: global row -> frame_digest. Returns the split document (None if unreadable)."""
    doc = _load_split(ds, name, check)
    if doc is None:
        return None
    _check_made_for(ds, doc, name, check)
    by_id = {ep["episode_id"]: ep for ep in ds.episodes}
    part_of = _check_membership(doc, name, by_id, check)
    _check_counts(doc, name, by_id, check)
    if hashes:
        _check_duplicate_frames(ds, part_of, hashes, check)
    return doc


def check_split_records(root, name: str, version: int | None = None, max_listed: int = 100) -> dict:
    """The split checks that read no sample, on a committed dataset: the split describes this version,
    every episode sits in one part, held-out (OOD) tasks only in ood (`ood_task_leak`), the stated counts
    add up. -> the splits Check as a dict (its failures include any the version's records had on load).
    What `htdata validate --split` adds: the byte-identical frames across parts (every shard read)."""
    check = Check("splits", max_listed)
    ds = load_dataset(Path(root), check, version)
    if ds is not None:
        check_splits(ds, name, {}, check)
    return check.to_dict()


def _check_made_for(ds: Loaded, doc: dict, name: str, check: Check) -> None:
    """The split describes this version: v1 names its manifest's sha256, v2 its episode file's.

    A carried split (v2, after rm/trim/append) warns about the episodes that
    left their part and those no part holds yet (run htdata split again).
    """
    if doc["format_version"] == 1:
        manifest_sha = hashlib.sha256(ds.manifest_bytes).hexdigest()
        if doc["manifest_sha256"] != manifest_sha:
            check.fail("split_manifest", f"split {name} was made from another {MANIFEST_FILE}",
                       expected=doc["manifest_sha256"], found=manifest_sha)
        return
    if doc["episodes_sha256"] != ds.manifest["episodes_sha256"]:
        check.fail("split_manifest", f"split {name} describes another episode list than this version's",
                   expected=doc["episodes_sha256"], found=ds.manifest["episodes_sha256"])
    carried = doc.get("carried") or {}
    if carried.get("left"):
        check.warn("split_episodes_left", f"split {name}: {len(carried['left'])} episode(s) left their part "
                   f"since version {carried['from_version']} (removed or trimmed away)", episodes=carried["left"])
    if carried.get("unassigned"):
        check.warn("split_unassigned", f"split {name}: {len(carried['unassigned'])} episode(s) are in no part "
                   f"yet; run htdata split --name {name} to assign them", episodes=carried["unassigned"])


def _load_split(ds: Loaded, name: str, check: Check) -> dict | None:
    path = split_path(ds.root, name, ds.manifest)
    if not path.is_file():
        known = list_splits(ds.root, ds.manifest)
        check.fail("split_missing", f"{path} not found; known splits: {', '.join(known) or '(none)'}",
                   file=str(path))
        return None
    data = path.read_bytes()
    entry = ds.manifest.get("splits", {}).get(name)
    if entry is not None and hashlib.sha256(data).hexdigest() != entry["sha256"]:
        check.fail("split_sha256", f"{path}: sha256 differs from the version's manifest", file=str(path),
                   expected=entry["sha256"], found=hashlib.sha256(data).hexdigest())
    try:
        doc = json.loads(data)
        validate_json(doc, "split", where=str(path))
    except ValueError as exc:
        check.fail("split_schema", str(exc), file=str(path))
        return None
    return doc


def _check_membership(doc: dict, name: str, by_id: dict[str, dict], check: Check) -> dict[str, list[str]]:
    """Known episodes, each in exactly one part, OOD tasks only in ood. Returns episode -> parts."""
    part_of: dict[str, list[str]] = defaultdict(list)
    for part in PARTS:
        for eid in doc["parts"][part]["episodes"]:
            part_of[eid].append(part)
            if eid not in by_id:
                check.fail("split_unknown_episode", f"split {name}: {part} lists unknown episode {eid}",
                           episode=eid, part=part)
    for eid, parts in part_of.items():
        if len(parts) > 1:
            check.fail("episode_in_two_parts", f"episode {eid} is in {' and '.join(parts)}",
                       episode=eid, found=parts)
    unassigned = set((doc.get("carried") or {}).get("unassigned", []))
    for eid in by_id:
        if eid not in part_of and eid not in unassigned:   # unassigned ones warn (_check_made_for)
            check.fail("episode_in_no_part", f"episode {eid} is in no part of split {name}", episode=eid)
    ood_tasks = set(doc["params"]["ood_tasks"])
    for part in ("train", "test"):
        for eid in doc["parts"][part]["episodes"]:
            if eid in by_id and by_id[eid]["task"] in ood_tasks:
                check.fail("ood_task_leak", f"episode {eid} of OOD task {by_id[eid]['task']} is in {part}",
                           episode=eid, part=part, task=by_id[eid]["task"])
    for eid, ep in by_id.items():
        if ep["task"] in ood_tasks and eid not in unassigned and "ood" not in part_of.get(eid, []):
            check.fail("ood_task_leak", f"episode {eid} of OOD task {ep['task']} is not in ood",
                       episode=eid, task=ep["task"])
    check.checked["episodes"] += len(part_of)
    return part_of


def _check_counts(doc: dict, name: str, by_id: dict[str, dict], check: Check) -> None:
    """Stated frames per part and ratios equal the parts' episodes; a test ratio far from the asked one warns."""
    frames = {p: sum(by_id[e]["num_frames"] for e in doc["parts"][p]["episodes"] if e in by_id)
              for p in PARTS}
    for part in PARTS:
        if doc["parts"][part]["frames"] != frames[part]:
            check.fail("split_frames", f"split {name}: {part} states {doc['parts'][part]['frames']} frames",
                       part=part, expected=frames[part], found=doc["parts"][part]["frames"])
    n = {p: len(doc["parts"][p]["episodes"]) for p in PARTS}
    achieved = {
        "test_of_in_distribution": {"episodes": n["test"] / max(n["train"] + n["test"], 1),
                                    "frames": frames["test"] / max(frames["train"] + frames["test"], 1)},
        "ood_of_all": {"episodes": n["ood"] / max(sum(n.values()), 1),
                       "frames": frames["ood"] / max(sum(frames.values()), 1)},
    }
    for ratio, vals in achieved.items():
        for unit, val in vals.items():
            stated = doc["ratios"][ratio][unit]
            if abs(stated - val) > 1e-9:
                check.fail("split_ratio", f"split {name}: {ratio}.{unit} states {stated:.6f}",
                           expected=round(val, 6), found=stated)
    _check_ratio_against_rule(doc, name, n, achieved["test_of_in_distribution"]["episodes"], check)


def _check_ratio_against_rule(doc: dict, name: str, n: dict[str, int], got: float, check: Check) -> None:
    """Warn when test is far from what the split's rule gives for its tasks, not from the bare ratio asked.

    The rule (htdata/store/splitrule.py) keeps a test episode in every task of 2+ episodes, so on a
    few small tasks it holds more than test_ratio on purpose; that is no reason to warn.
    """
    asked = doc["params"]["test_ratio"]
    sizes = {task: c.get("train", {}).get("episodes", 0) + c.get("test", {}).get("episodes", 0)
             for task, c in doc["tasks"].items()}
    n_in = max(n["train"] + n["test"], 1)
    expected = sum(test_counts({t: k for t, k in sizes.items() if k}, asked).values()) / n_in
    if abs(got - expected) > max(0.05, 1.0 / n_in):
        check.warn("split_ratio_far", f"split {name}: test holds {got:.3f} of in-distribution episodes; "
                   f"its rule gives {expected:.3f} for these tasks (asked {asked})",
                   expected=round(expected, 4), found=round(got, 4))


def _check_duplicate_frames(ds: Loaded, part_of: dict[str, list[str]], hashes: dict[int, str],
                            check: Check) -> None:
    """Rows with the same frame_digest must all sit in one part."""
    eids = [ep["episode_id"] for ep in ds.episodes]
    groups: dict[str, list[int]] = defaultdict(list)
    for row, digest in hashes.items():
        groups[digest].append(row)
    for digest, rows in groups.items():
        if len(rows) < 2:
            continue
        labelled = []
        for r in rows:
            eid = eids[int(ds.index["episode"][r])]
            part = (part_of.get(eid) or ["none"])[0]
            labelled.append((part, sample_key(eid, int(ds.index["frame"][r]))))
        if len({p for p, _ in labelled}) > 1:
            check.fail("duplicate_frame_across_parts",
                       "byte-identical frame in several parts: "
                       + ", ".join(f"{k} ({p})" for p, k in sorted(labelled)),
                       keys=[k for _, k in sorted(labelled)], parts=sorted({p for p, _ in labelled}),
                       sha256=digest)
    check.checked["frames_hashed"] += len(hashes)
