"""`htdata rm` / `htdata trim`: remove episodes or frames as a new version, never in place.

Both plan first (`plan_edit`: which episodes go, which frames stay, which
work units must be re-packed, which shards the new version stops listing)
and only then write; `--dry-run` prints the plan and writes nothing. A work
unit none of whose episodes is touched is reused as is; a unit all of whose
episodes are removed is dropped from the new version's list (its shards
stay on disk for the versions that list them, until `htdata gc`); any other
touched unit is re-packed into a new unit (htdata/write/repack.py). Splits carry
over: a removed episode leaves its part, the rest keep theirs.

An id or glob that matches no episode is an error listing near matches
(htdata/store/episodeids.py, the line every command gives): never "removed 0" with exit 0, never a removal of something else.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from htdata._moved import moved_name
from htdata.errors import ArgumentError
from htdata.store.episodeids import resolve_episodes
from htdata.store.snapshot import Snapshot
from htdata.write.newversion import NewVersion
from htdata.write.repack import KeptEpisode


def parse_frames(spec: str, n: int, episode: str) -> range:
    """'A:B' (Python slice, A or B may be empty) -> the frames KEPT of an n-frame episode."""
    try:
        a, b = spec.split(":")
        start, stop = int(a) if a.strip() else 0, int(b) if b.strip() else n
    except ValueError:
        raise ArgumentError(f"--frames must be A:B (frames kept, B exclusive), got {spec!r}") from None
    if not 0 <= start < stop <= n:
        raise ArgumentError(f"episode {episode!r} has frames 0..{n - 1}: --frames {spec} must keep a non-empty "
                            f"range inside 0:{n} (to remove the whole episode use htdata rm)")
    return range(start, stop)


@dataclass
class Edit:
    """What an rm/trim changes, against parent version `parent`."""
    parent: int | None
    removed: list[str] = field(default_factory=list)
    trimmed: dict[str, range] = field(default_factory=dict)
    repacked_units: list[int] = field(default_factory=list)
    dropped_shards: list[str] = field(default_factory=list)
    frames_removed: int = 0

    def lines(self, dry_run: bool = False) -> list[str]:
        would = "would " if dry_run else ""
        out = [f"{would}remove episode {e}" for e in self.removed]
        out += [f"{would}trim episode {e}: keep frames {r.start}:{r.stop}" for e, r in self.trimmed.items()]
        if self.repacked_units:     # one line each, however many: a dataset-wide trim touches every unit
            out.append(f"{would}re-pack {_count(self.repacked_units, 'work unit')} "
                       f"({_span(self.repacked_units)}; their other samples are copied into new shards)")
        if self.dropped_shards:
            out.append(f"{would}stop listing {_count(self.dropped_shards, 'shard')} ({_span(self.dropped_shards)})")
        out.append(f"{self.frames_removed} frames {'would be ' if dry_run else ''}removed")
        return out


def _count(items: list, what: str) -> str:
    return f"{len(items)} {what}{'' if len(items) == 1 else 's'}"


def _span(items: list) -> str:
    """The items named when few, else the first and last: a summary stays one short line."""
    names = [str(i) for i in items]
    return ", ".join(names) if len(names) <= 3 else f"{names[0]} .. {names[-1]}"


def plan_edit(snap: Snapshot, remove: list[str], trim: dict[str, range]) -> tuple[Edit, list]:
    """(Edit, [(part, kept episodes or None if untouched)]) for removing/trimming episodes."""
    edit = Edit(parent=snap.version, removed=list(remove), trimmed=dict(trim))
    plan = []
    for part in snap.parts():
        touched = [e for e in part.episode_ids if e in remove or e in trim]
        if not touched:
            plan.append((part, None))
            continue
        kept = []
        for rec in part.episodes:
            eid, n = rec["episode_id"], int(rec["num_frames"])
            if eid in remove:
                edit.frames_removed += n
            elif eid in trim:
                kept.append(KeptEpisode(record=_trimmed_record(rec, trim[eid], snap.version), frames=trim[eid]))
                edit.frames_removed += n - len(trim[eid])
            else:
                kept.append(KeptEpisode.whole(rec))
        if kept:
            edit.repacked_units.append(part.unit)
        edit.dropped_shards += [s["name"] for s in part.shards]
        plan.append((part, kept))
    return edit, plan


def _trimmed_record(rec: dict, frames: range, version: int | None) -> dict:
    rec = dict(rec)
    n = int(rec["num_frames"])
    stats = dict(rec.get("stats", {}))
    stats["frames_kept"] = len(frames)
    rec["stats"] = stats
    rec["trimmed"] = {"start": frames.start, "stop": frames.stop, "of": n}
    rec["notes"] = list(rec.get("notes", [])) + [
        f"trimmed to frames {frames.start}..{frames.stop - 1} of {n} (from version {version}); "
        f"frames renumbered from 0, source_frame / t_rgb_ns in each sample keep the original time; "
        f"contact stats describe the untrimmed episode"]
    return rec


def apply_edit(nv: NewVersion, plan: list) -> dict:
    """Write the planned version (re-packing touched units into new ones) in `nv`; returns its manifest."""
    kept_of = {part.unit: kept for part, kept in plan}     # plan_edit's, over nv.parent: None = untouched
    return nv.commit(nv.carry_or_repack(lambda part: part if kept_of[part.unit] is None else kept_of[part.unit]))


def remove_episodes(root, patterns: list[str], dry_run: bool, command: str) -> tuple[Edit, dict | None]:
    with NewVersion(root, command) as nv:
        edit, plan = plan_edit(nv.parent, resolve_episodes(nv.parent.episode_ids(), patterns), {})
        return edit, None if dry_run else apply_edit(nv, plan)


def trim_episode(root, episode: str, frames: str, dry_run: bool, command: str) -> tuple[Edit, dict | None]:
    with NewVersion(root, command) as nv:
        snap = nv.parent
        ids = resolve_episodes(snap.episode_ids(), [episode])
        if len(ids) != 1:
            raise ArgumentError(f"trim takes one episode; {episode!r} matches {len(ids)}: {', '.join(ids[:5])}")
        eid = ids[0]
        n = next(int(e["num_frames"]) for e in snap.episodes if e["episode_id"] == eid)
        kept = parse_frames(frames, n, eid)
        if kept == range(n):     # keeps every frame: the version would be identical, so none is written
            return Edit(parent=snap.version), None
        edit, plan = plan_edit(snap, [], {eid: kept})
        return edit, None if dry_run else apply_edit(nv, plan)


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
