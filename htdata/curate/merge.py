"""`htdata merge A B OUT`: one dataset from two, without re-encoding.

A's shards keep their names; B's work units are renumbered after A's, so
B's shards get new names (a shard's bytes do not contain its name, so its
sha256 stays). Shards are hard-linked when A, B and OUT share a file system,
copied otherwise, and every one is verified against its recorded sha256.
Refused with a message naming what differs: another canonical template,
another codec, a layout id whose document differs, an episode id present in
both with different content. The same episode with the same content (record
and every sample's bytes) is kept once, from A, and reported. OUT starts at
version 1 with no splits (a merged dataset needs its own `htdata split`).
The merge takes OUT's writer lock FIRST and only then looks at OUT, so two
merges started together into one OUT cannot both decide it is theirs: the
second is refused (locked, or OUT already holds a dataset) and deletes
nothing. Holding the lock in an empty OUT, the merge writes the marker
`OUT/.merge.json` (A, B and their versions) before anything else and removes
it after its commit. A merge killed in between leaves that marker: running
the same merge again resumes (shards already placed and sha256-verified are
kept, temp files and re-packed units are redone; a version already committed
is just finished). Leftovers without the marker, or a marker naming another
merge, are never touched: the command refuses, naming them.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from htdata.errors import ArgumentError
from htdata.faults import crash_point
from htdata.fileio import write_bytes_atomic
from htdata.format.mapstorage import MapStorage
from htdata.format.shardio import shard_name
from htdata.format.table import MANIFEST_FILE, SHARDS_DIR
from htdata.read.reader import DatasetReader
from htdata.store.confine import inside
from htdata.store.fsutil import sha256_file
from htdata.store.lock import is_lock_file
from htdata.store.manifest import load_manifest
from htdata.store.parts import Part
from htdata.store.snapshot import Snapshot, open_snapshot
from htdata.store.versions import content_view, list_versions, version_manifest_file
from htdata.write.newversion import NewVersion
from htdata.write.repack import KeptEpisode

MERGE_MARKER = ".merge.json"   # written by a merge into an empty OUT, removed after its commit


class MergeConflict(ArgumentError):
    """The two datasets cannot be merged as they are."""


@dataclass
class MergeReport:
    episodes_a: int = 0
    episodes_b: int = 0
    deduplicated: list[str] = field(default_factory=list)
    linked: int = 0
    copied: int = 0
    resumed: int = 0       # shards an interrupted run of the same merge had placed (sha256-verified)
    manifest: dict | None = None

    def lines(self) -> list[str]:
        out = [f"{self.episodes_a} episodes from A, {self.episodes_b} from B"]
        if self.deduplicated:
            out.append(f"{len(self.deduplicated)} episodes in both with identical content, kept once: "
                       f"{', '.join(self.deduplicated[:5])}{' ...' if len(self.deduplicated) > 5 else ''}")
        out.append(f"shards: {self.linked} hard-linked, {self.copied} copied, all sha256-verified")
        if self.resumed:
            out.append(f"resumed an interrupted merge: {self.resumed} shards it had placed kept (sha256-verified)")
        return out


def check_compatible(a: Snapshot, b: Snapshot) -> None:
    ma, mb = a.manifest, b.manifest
    if ma["canonical"]["sha256"] != mb["canonical"]["sha256"]:
        raise MergeConflict(f"different canonical hand templates (sha256 {ma['canonical']['sha256'][:12]} in "
                            f"{a.root} vs {mb['canonical']['sha256'][:12]} in {b.root})")
    # the settings must agree; codec.choice only says how each dataset arrived at them (reason texts differ)
    # maps stored or rendered from raw rows (codec.tactile.maps, absent = stored) is one choice per version
    ca, cb = MapStorage.comparable_codec(ma["codec"]), MapStorage.comparable_codec(mb["codec"])
    keys = sorted({f"{k}.{s}" for k in ("tactile", "rgb") for s in set(ca.get(k, {}))
                   | set(cb.get(k, {})) if ca.get(k, {}).get(s) != cb.get(k, {}).get(s)})
    if keys:
        raise MergeConflict(f"different codec settings: {', '.join(keys)}"
                            + (f" (maps {ca['tactile']['maps']} vs {cb['tactile']['maps']}: a version either stores "
                               f"its maps or not; re-ingest one with the other's [tactile] maps)"
                               if "tactile.maps" in keys else ""))
    for lid in set(ma["layouts"]) & set(mb["layouts"]):
        if ma["layouts"][lid]["sha256"] != mb["layouts"][lid]["sha256"]:
            raise MergeConflict(f"layout {lid!r} differs between {a.root} and {b.root} (same id, other document)")


def episode_digest(reader: DatasetReader, episode_id: str) -> str:
    """sha256 over every member of every sample of an episode (exact content identity)."""
    h = hashlib.sha256()
    first, n = reader.episode_range(episode_id)
    for i in range(first, first + n):
        for suffix, data in reader.sample(i).items():
            h.update(suffix.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    return h.hexdigest()


def duplicates(a: Snapshot, b: Snapshot) -> list[str]:
    """Episode ids in both with identical content; raises MergeConflict on one whose content differs."""
    rec_a = {e["episode_id"]: e for e in a.episodes}
    same = []
    ra, rb = DatasetReader(a.root, version=a.version), DatasetReader(b.root, version=b.version)
    for ep in b.episodes:
        eid = ep["episode_id"]
        if eid not in rec_a:
            continue
        if content_view(rec_a[eid]) != content_view(ep) or episode_digest(ra, eid) != episode_digest(rb, eid):
            raise MergeConflict(f"episode {eid!r} is in both datasets with different content "
                                f"(remove it from one with htdata rm, or rename it)")
        same.append(eid)
    return same


def place_shard(src: Path, dst: Path, sha256: str, report: MergeReport, resuming: bool = False) -> None:
    if dst.exists():
        if resuming and sha256_file(dst) == sha256:   # placed by the interrupted run of this merge
            report.resumed += 1
            return
        if not resuming:
            raise MergeConflict(f"{dst} already exists")
        dst.unlink()
    try:
        os.link(src, dst)
        report.linked += 1
    except OSError:      # another file system (or no hard links): copy
        shutil.copyfile(src, dst)
        report.copied += 1
    if sha256_file(dst) != sha256:
        dst.unlink()
        raise MergeConflict(f"{src}: sha256 does not match its manifest entry; the source shard is damaged "
                            f"(run htdata validate on it)")


def _renamed(part: Part, unit: int) -> Part:
    shards = [{**s, "name": shard_name(unit, k)} for k, s in enumerate(part.shards)]
    return Part(unit=unit, shards=shards, rows=part.rows, episodes=part.episodes)


def _intent(a: Snapshot, b: Snapshot) -> dict:
    return {"a": str(Path(a.root).resolve()), "a_version": a.version,
            "b": str(Path(b.root).resolve()), "b_version": b.version}


def _claim(out: Path, intent: dict) -> bool:
    """Under OUT's lock: True when resuming an interrupted run of this merge, False for a fresh OUT
    (the marker is then written); MergeConflict for anything else, with nothing touched."""
    marker = out / MERGE_MARKER
    if marker.is_file():
        try:
            found = json.loads(marker.read_text())
        except ValueError:
            found = None
        if found != intent:
            what = f"of {found.get('a')} and {found.get('b')}" if isinstance(found, dict) else "(unreadable marker)"
            raise MergeConflict(f"{out}: holds an interrupted merge {what}; run that merge again to finish it, "
                                f"or choose a new directory")
        return True
    if [p.name for p in out.iterdir() if not is_lock_file(p.name)]:
        raise MergeConflict(f"{out}: not empty; merge writes a new dataset (choose a new directory)")
    write_bytes_atomic(marker, (json.dumps(intent) + "\n").encode())
    return False


def merge(a_root, b_root, out_root, command: str) -> MergeReport:
    a, b = open_snapshot(a_root), open_snapshot(b_root)
    check_compatible(a, b)
    out = Path(out_root)
    if out.exists() and not out.is_dir():
        raise MergeConflict(f"{out}: exists and is not a directory; merge writes a new dataset")
    dup = set(duplicates(a, b))
    report = MergeReport(episodes_a=len(a.episodes), episodes_b=len(b.episodes) - len(dup), deduplicated=sorted(dup))
    out.mkdir(parents=True, exist_ok=True)
    # the lock first: only its holder may decide what OUT's files are; B's units follow A's; resumable
    with NewVersion(out, command, parent="none", first_unit=a.next_unit(), resumable=True) as nv:
        resuming = _claim(out, _intent(a, b))
        if resuming and list_versions(out):   # killed after its version file: the merge is committed
            head = out / version_manifest_file(list_versions(out)[-1])
            write_bytes_atomic(out / MANIFEST_FILE, head.read_bytes())
            (out / MERGE_MARKER).unlink()
            report.manifest = load_manifest(out)
            return report
        for tmp in out.rglob(".*.tmp"):       # this merge's own temp files (the marker says OUT is ours)
            if not is_lock_file(tmp.name):   # a lock temp file belongs to a writer trying the lock now
                tmp.unlink(missing_ok=True)
        (out / SHARDS_DIR).mkdir(exist_ok=True)

        def carry_a(part: Part) -> Part:     # A's parts keep their units: their shards are placed as named
            for s in part.shards:
                place_shard(a.root / SHARDS_DIR / s["name"], out / SHARDS_DIR / s["name"], s["sha256"], report,
                            resuming)
            return part
        parts = nv.carry_or_repack(carry_a, parent=a)

        def choose_b(part: Part) -> Part | list[KeptEpisode] | None:
            kept = [e for e in part.episodes if e["episode_id"] not in dup]
            if not kept:
                return None
            if len(kept) < len(part.episodes):   # re-pack B's unit without the duplicate, into OUT (an
                # interrupted run's try at that unit is redone: NewVersion.repack writes a unit whole)
                return [KeptEpisode.whole(e) for e in kept]
            renamed = _renamed(part, nv.take_unit())
            for old, new in zip(part.shards, renamed.shards):
                place_shard(b.root / SHARDS_DIR / old["name"], out / SHARDS_DIR / new["name"], old["sha256"],
                            report, resuming)
            return renamed
        parts += nv.carry_or_repack(choose_b, parent=b, reader=DatasetReader(b.root, version=b.version))
        crash_point("merge_shards_placed")
        copy_layout_files(a, out)
        copy_layout_files(b, out)
        fields = {"sources": a.manifest["sources"] + b.manifest["sources"],
                  "layouts": {**b.manifest["layouts"], **a.manifest["layouts"]},
                  "canonical": a.manifest["canonical"], "codec": a.manifest["codec"],
                  # content ids: the same calibration in A and B is one entry (revisions renumbered)
                  "calibrations": {**b.manifest.get("calibrations", {}), **a.manifest.get("calibrations", {})}}
        report.manifest = nv.commit(parts, fields)    # no parent: no splits (a merged dataset needs its own)
        crash_point("merge_committed")
        (out / MERGE_MARKER).unlink()
    return report


def copy_layout_files(snap: Snapshot, out: Path) -> None:
    """The layout, coverage and canonical files `snap`'s manifest names, copied under the same paths."""
    m = snap.manifest
    paths = [p for entry in m["layouts"].values() for p in (entry["file"], entry["coverage"])]
    paths += [m["canonical"][k] for k in ("file", "regions", "parts") if k in m["canonical"]]
    for rel in paths:
        src, dst = Path(inside(snap.root, rel)), out / rel   # never a file from outside the dataset
        if dst.exists():
            if dst.read_bytes() != src.read_bytes():
                raise MergeConflict(f"{rel} differs between the two datasets")
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
