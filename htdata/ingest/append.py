"""Ingest into an existing dataset: what to re-do, what to keep, and the parts of the new version.

An ingest never starts over. Against the current version (the parent):
- an episode whose inputs are unchanged (same `input_fingerprint`: source
  files, layout files, the pipeline settings that shape a sample) is reused
  as committed; if only its labels changed (task, scene, source_ref,
  source_split: an edited annotation table) its record is updated and its
  samples stay where they are ("relabelled");
- an episode with changed inputs is re-ingested and replaces its old
  samples ("replaced"); if that re-ingest fails, the parent's copy is kept
  and the failure reported;
- a parent episode this run did not discover (another source, a source
  file now missing or unreadable) is KEPT; removal is `htdata rm`'s job.
Work units are one episode each, numbered from the parent's `next_unit`, so
appending an episode to a large dataset costs that episode plus one pass
over the index (assemble), never a re-pack of the rest.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from htdata.store.parts import Part
from htdata.store.snapshot import Snapshot
from htdata.write.newversion import NewVersion
from htdata.write.repack import KeptEpisode

# Pipeline sections that do not shape a sample (packing and naming only).
NOT_SAMPLE_SETTINGS = ("name", "shards")


def input_fingerprint(ref, pipeline: dict) -> str:
    """sha1 over the ref's fingerprint (source + layout files) and the pipeline's sample settings."""
    settings = {k: v for k, v in pipeline.items() if k not in NOT_SAMPLE_SETTINGS}
    return hashlib.sha1(json.dumps([ref.fingerprint, settings], sort_keys=True).encode()).hexdigest()


def labels_of(ref) -> dict:
    """The label fields a ref gives its record, not its samples (source_split None = the record has none)."""
    split = ref.extra.get("source_split") if isinstance(ref.extra, dict) else None
    return {"task": ref.task, "scene": ref.scene, "source_ref": ref.source_ref,
            "source_split": str(split) if split else None}


def relabel(record: dict, labels: dict) -> dict:
    out = {**record, **{k: v for k, v in labels.items() if v is not None}}
    for k in (k for k, v in labels.items() if v is None):
        out.pop(k, None)
    return out


@dataclass
class AppendPlan:
    """The decision for every discovered episode against the parent version."""
    parent: Snapshot | None
    todo: list = field(default_factory=list)                    # refs to ingest (new or changed)
    replaced: set[str] = field(default_factory=set)             # changed ids (subset of todo)
    relabelled: dict[str, dict] = field(default_factory=dict)   # id -> new label fields
    reused: list[str] = field(default_factory=list)             # unchanged ids

    def summary(self) -> dict:
        return {"new": len(self.todo) - len(self.replaced), "replaced": sorted(self.replaced),
                "relabelled": sorted(self.relabelled), "reused": len(self.reused)}


def plan_append(parent: Snapshot | None, refs: list, pipelines: list[dict]) -> AppendPlan:
    """Decide per ref (refs[i] comes from pipelines[i]): reuse, relabel, or (re-)ingest.

    Refs come back with `fingerprint` = their input fingerprint, the value
    their episode record keeps as "input_fingerprint".
    """
    plan = AppendPlan(parent=parent)
    old = {e["episode_id"]: e for e in (parent.episodes if parent else [])}
    for ref, pipeline in zip(refs, pipelines):
        ref = dataclasses.replace(ref, fingerprint=input_fingerprint(ref, pipeline))
        rec = old.get(ref.episode_id)
        if rec is None:
            plan.todo.append(ref)
        elif rec.get("input_fingerprint") != ref.fingerprint:
            plan.todo.append(ref)
            plan.replaced.add(ref.episode_id)
        else:
            labels = labels_of(ref)
            if any(rec.get(k) != v for k, v in labels.items()):
                plan.relabelled[ref.episode_id] = labels
            else:
                plan.reused.append(ref.episode_id)
    return plan


def kept_unavailable(parent: Snapshot | None, discovered: set[str], roots: list[Path]) -> list[str]:
    """Parent episodes from these source roots that this run did not discover (kept, reported)."""
    if parent is None:
        return []
    prefixes = tuple(str(r).rstrip("/") + "/" for r in roots)
    return sorted(e["episode_id"] for e in parent.episodes
                  if e["episode_id"] not in discovered and str(e.get("source_ref", "")).startswith(prefixes))


def parent_parts(plan: AppendPlan, ingested: set[str], nv: NewVersion) -> list[Part]:
    """The parent's parts in the new version: replaced episodes leave, relabelled ones get new labels.

    A part that keeps some episodes but loses others (datasets written
    before one-episode units) is re-packed into the next free unit of the ingest's transaction `nv`.
    """
    if plan.parent is None:
        return []
    gone = plan.replaced & ingested

    def choose(part: Part) -> Part | list[KeptEpisode]:
        records = [relabel(e, plan.relabelled[e["episode_id"]]) if e["episode_id"] in plan.relabelled else e
                   for e in part.episodes]
        kept = [e for e in records if e["episode_id"] not in gone]
        if len(kept) == len(records):
            return Part(unit=part.unit, shards=part.shards, rows=part.rows, episodes=records)
        return [KeptEpisode.whole(e) for e in kept]      # none kept: the part leaves
    return nv.carry_or_repack(choose, parent=plan.parent)
