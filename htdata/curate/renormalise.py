"""`htdata renormalise`: new maps from the stored raw glove rows under a new calibration, as a new version.

A glove recalibrated after its recordings were archived needs no sources:
every format-3 sample stores its raw rows exactly (raw_<hand>.npy) and the
row paired with its frame. For each episode hand whose calibration the
pipeline changes (its `[normalise.<layout>]`, or the layout's value block),
the paired rows are normalised under the new settings, rasterised in the
dataset's raster mode and re-encoded with the dataset's codec; JSON, RGB and
raw members are copied byte for byte. A calibration that fits per-episode
arrays (baseline, noise floor) is fitted on the episode's first stored
frames, as the ingest does (`chunk_frames` paired rows; frames the ingest
dropped are not stored, so an episode that lost frames at its very start may
fit slightly differently than a fresh ingest would). An unchanged
calibration is skipped, unless `force`: then the recorded fitted arrays are
restored and the maps come out byte for byte as stored (the test of the
whole path). Work units holding a changed episode are re-packed into new
units (htdata/write/repack.py); everything else is reused; `dry_run` plans only.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.curate.edit import resolve_episodes
from htdata.errors import ArgumentError, ConfigError, DatasetError
from htdata.format.codec import MEMBER_CODECS
from htdata.format.mapstorage import MapStorage, hand_present, has_hand
from htdata.format.table import (
    JSON_MEMBER,
    SIZE_FIELDS,
    CodecSettings,
    bend_member,
    decode_member,
    raw_member,
    tactile_member,
)
from htdata.glove.calibration import (
    episode_calibrations,
    episode_normaliser,
    fit_digests,
    fit_record,
    taxel_digest,
)
from htdata.glove.health import record_entry
from htdata.glove.layouts import Layout, load_layout
from htdata.glove.normalise import Normaliser
from htdata.glove.normalisesettings import NormaliseSettings
from htdata.glove.pooledrest import GloveRest, reused_rest, spread, write_work_reference
from htdata.glove.rasterise import Rasteriser
from htdata.glove.restlevel import rest_level_warning
from htdata.glove.restreference import MIN_RECORDINGS, pooled_reference, recording_rest
from htdata.read.rawstream import apply_paired, paired_row, paired_source_row
from htdata.read.reader import DatasetReader
from htdata.store.confine import inside
from htdata.store.snapshot import Snapshot
from htdata.write.newversion import NewVersion
from htdata.write.repack import KeptEpisode


@dataclass
class RenormalisePlan:
    """What a renormalise changes against version `parent`: episode -> hand -> (old id, new id)."""
    parent: int | None
    changes: dict[str, dict[str, tuple[str | None, str]]] = field(default_factory=dict)
    unchanged: int = 0
    repacked_units: list[int] = field(default_factory=list)
    calibrations: dict[str, dict] = field(default_factory=dict)   # new id -> manifest entry
    warnings: dict[str, list[str]] = field(default_factory=dict)  # episode -> lines (the ingest's rest-level warning)
    notes: list[str] = field(default_factory=list)                 # the glove rests given (htdata.glove.pooledrest)

    def lines(self, dry_run: bool = False) -> list[str]:
        would = "would " if dry_run else ""
        out = [f"{would}renormalise {eid} {hand}: calibration {old or '(none)'} -> {new}"
               for eid, hands in self.changes.items() for hand, (old, new) in hands.items()]
        out += [f"{would}re-pack work unit {u}" for u in self.repacked_units]
        out.append(f"{len(self.changes)} episode(s) {would}renormalised, {self.unchanged} unchanged")
        return out


def dataset_layouts(snap: Snapshot) -> dict[str, Layout]:
    """The glove layouts a version lists, loaded from the dataset's own layout files."""
    return {lid: load_layout(Path(inside(snap.root, entry["file"], f"layouts.{lid}.file")))
            for lid, entry in snap.manifest["layouts"].items()}


def plan_renormalise(snap: Snapshot, layouts: dict[str, Layout], normalising: NormaliseSettings,
                     patterns: list[str] | None = None, force: bool = False) -> RenormalisePlan:
    """Which episode hands get a new calibration; refuses episodes stored without raw rows (naming them).
    `layouts`: the version's (dataset_layouts)."""
    chosen = set(resolve_episodes(snap.episode_ids(), patterns) if patterns else snap.episode_ids())
    # A [normalise.<id>] (or --set normalise.<id>.*) no chosen episode uses would change nothing: a typo.
    scope = f"dataset {snap.root} version {snap.version}" + (f" (episodes {', '.join(patterns)})" if patterns else "")
    normalising.check_layout_names({lid for ep in snap.episodes if ep["episode_id"] in chosen
                                 for lid in ep["layouts"].values()}, None, scope)
    plan = RenormalisePlan(parent=snap.version)
    no_raw = []
    resolved: dict[str, tuple[str, dict]] = {}   # layout id -> (new calibration id, its entry): once per layout
    for pos, ep in enumerate(snap.episodes):
        eid = ep["episode_id"]
        hands = {}
        for hand in ep["hands"] if eid in chosen else ():
            lid = ep["layouts"][hand]
            if lid not in resolved:      # one layout: one calibration, {id: entry}
                (resolved[lid],) = episode_calibrations(normalising, {hand: layouts[lid]}).items()
            new, entry = resolved[lid]
            old = (ep.get("calibration") or {}).get(hand)
            if new != old or force:
                hands[hand] = (old, new)
                plan.calibrations[new] = entry
        if not hands:
            plan.unchanged += 1
            continue
        rows = snap.index[snap.index["episode"] == pos]
        if not all(raw_rows_stored(rows, h) for h in hands):
            no_raw.append(eid)
        plan.changes[eid] = hands
    if no_raw:
        raise ArgumentError(f"{len(no_raw)} episode(s) have no stored raw glove rows (format < 3, or ingested with "
                            f"[tactile] keep_raw = false), so they cannot be renormalised without their sources: "
                            f"{', '.join(no_raw[:5])}{' ...' if len(no_raw) > 5 else ''}; re-ingest them instead")
    for part in snap.parts():
        if any(e in plan.changes for e in part.episode_ids):
            plan.repacked_units.append(part.unit)
    return plan


def rest_level_warnings(reader: DatasetReader, snap: Snapshot, layouts: dict[str, Layout],
                        normalising: NormaliseSettings, plan: RenormalisePlan) -> None:
    """Fill plan.warnings as an ingest would warn: a raw-count glove whose rest reads as pressure under the new
    settings (baseline "none"), judged on the episode hand's first stored paired rows."""
    records = {ep["episode_id"]: ep for ep in snap.episodes}
    for eid, hands in plan.changes.items():
        for hand in hands:
            layout = layouts[records[eid]["layouts"][hand]]
            cfg = normalising.normalise_for(layout)
            if cfg.subtracts_rest:
                continue
            rows = first_paired_rows(reader, eid, hand, normalising.fit_frames).astype(np.float32)
            with np.errstate(invalid="ignore"):
                lo, hi = np.nanmin(rows, axis=0), np.nanmax(rows, axis=0)
            line = rest_level_warning(hand, layout, cfg, lo, hi)
            if line:
                plan.warnings.setdefault(eid, []).append(f"{line} (episode {eid})")


def first_paired_rows(reader: DatasetReader, eid: str, hand: str, frames: int) -> np.ndarray:
    """The paired raw rows of the episode's first `frames` frames holding the hand (what the ingest fitted on)."""
    first, n = reader.episode_range(eid)
    rows = []
    for i in range(first, first + n):
        if len(rows) == frames:
            break
        members = reader.sample(i, (JSON_MEMBER, tactile_member(hand), raw_member(hand)))
        if has_hand(members, hand):   # RGB-only samples hold no rows
            rows.append(paired_row(members, hand, f"{eid} frame {i - first}"))
    return np.stack(rows)


def paired_rows(reader: DatasetReader, eid: str, hand: str) -> tuple[np.ndarray, float, np.ndarray]:
    """(paired raw rows, glove fps, their source row numbers) of the whole episode, each source row once
    (what the ingest fits the baselines chosen by activity on)."""
    first, n = reader.episode_range(eid)
    rows, numbers, times = [], [], []
    for i in range(first, first + n):
        members = reader.sample(i, (JSON_MEMBER, tactile_member(hand), raw_member(hand)))
        if has_hand(members, hand):   # RGB-only samples hold no rows
            where = f"{eid} frame {i - first}"
            number = paired_source_row(members, hand, where)
            if numbers and number == numbers[-1]:
                continue
            rows.append(paired_row(members, hand, where))
            numbers.append(number)
            meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], where)
            times.append(int(meta["t_tactile_ns"][hand]))
    step = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    return np.stack(rows), (1e9 / step if step > 0 else 30.0), np.asarray(numbers, np.int64)


def raw_rows_stored(rows: np.ndarray, hand: str) -> bool:
    """Every sample of these index rows that holds the hand (RGB-only samples hold no map) stores its raw row."""
    mapped = hand_present(rows, hand)
    return bool(np.all(rows[SIZE_FIELDS[raw_member(hand)]][mapped] > 0))


def dataset_glove_rests(work: Path, snap: Snapshot, layouts: dict[str, Layout], reader: DatasetReader,
                        normalising: NormaliseSettings) -> tuple[NormaliseSettings, list[GloveRest]]:
    """`normalising` with the glove's own rest for each raw-count layout it leaves to the default (as an ingest
    of many recordings gives it: htdata/ingest/gloverest.py): the reference the dataset's episodes already
    have, else one pooled over the raw rows the dataset stores of at least MIN_RECORDINGS episodes of the
    glove. The reference files go to `work`'s work folder."""
    found = {}
    for lid, layout in sorted(layouts.items()):
        if normalising.default_note(layout) is None:
            continue
        had = reused_rest(work, snap, layout)
        if had is not None:
            found[lid] = had
            continue
        hands = []
        for pos, ep in enumerate(snap.episodes):
            rows = snap.index[snap.index["episode"] == pos]
            hands += [(ep["episode_id"], h) for h, used in sorted(ep["layouts"].items())
                      if used == lid and hand_present(rows, h).any() and raw_rows_stored(rows, h)]
        if len(hands) < MIN_RECORDINGS:
            continue
        rests = [recording_rest(paired_rows(reader, eid, h)[0], layout.value["convention"])
                 for eid, h in spread(hands)]
        found[lid] = GloveRest(lid, write_work_reference(work, lid, pooled_reference(rests)), len(rests),
                               pooled_over="episodes of the dataset (their stored raw rows)")
    if not found:
        return normalising, []
    return normalising.with_glove_rests({lid: r.path for lid, r in found.items()}), list(found.values())


class Recalibration:
    """The SampleRewrite of a renormalise: new maps (and bend vectors) for the changed episode hands."""

    def __init__(self, reader: DatasetReader, snap: Snapshot, layouts: dict[str, Layout],
                 normalising: NormaliseSettings, plan: RenormalisePlan):
        self.reader, self.snap, self.normalising, self.plan = reader, snap, normalising, plan
        self.layouts = layouts
        codec = snap.manifest["codec"]["tactile"]
        self.raster_mode = codec.get("raster_mode", "nearest")
        self.settings = CodecSettings(tactile_compression=codec.get("compression", "zip"),
                                      tactile_pixel_type=codec.get("pixel_type", "half"))   # the dataset's maps
        self.records = {ep["episode_id"]: ep for ep in snap.episodes}
        self.store_maps = MapStorage.of(snap.manifest).stores_maps
        # episode -> hand -> (normaliser, rasteriser, [contact sum, max], live-value rows for taxel health)
        self.state: dict[str, dict] = {}

    def _start(self, eid: str) -> dict:
        ep = self.records[eid]
        state = {}
        for hand, (_, new) in self.plan.changes[eid].items():
            layout = self.layouts[ep["layouts"][hand]]
            if new == (ep.get("calibration") or {}).get(hand):   # forced: restore what the ingest fitted
                normaliser = episode_normaliser(self.snap.manifest, ep, hand, layout)
            else:
                normaliser = Normaliser(self.normalising.normalise_for(layout), layout)
                if normaliser.cfg.per_episode:      # chosen by activity: fitted on every paired row
                    normaliser.fit_episode(*self._paired_rows(eid, hand))
                else:
                    normaliser.fit_baseline(self._first_rows(eid, hand))
            state[hand] = (normaliser, Rasteriser(layout, mode=self.raster_mode), [0.0, 0.0], [])
        self.state = {eid: state}    # one episode at a time: repack walks episodes in order
        return state

    def _first_rows(self, eid: str, hand: str) -> np.ndarray:
        """The paired raw rows of the episode's first `chunk_frames` frames (what the ingest fitted on)."""
        return first_paired_rows(self.reader, eid, hand, self.normalising.fit_frames)

    def _paired_rows(self, eid: str, hand: str) -> tuple[np.ndarray, float, np.ndarray]:
        return paired_rows(self.reader, eid, hand)

    def members(self, episode_id: str, frame: int, members: dict[str, bytes]) -> dict[str, bytes]:
        if episode_id not in self.plan.changes:
            return members
        state = self.state.get(episode_id) or self._start(episode_id)
        out = dict(members)
        for hand, (normaliser, raster, contact, series) in state.items():
            if not has_hand(members, hand):   # an RGB-only sample: nothing to renormalise
                continue
            where = f"{episode_id} frame {frame} {hand} hand"
            try:
                values, finite = apply_paired(normaliser, members, hand, where)
            except ValueError as exc:   # e.g. clip = false and a value outside [0,1] under the new settings
                raise ConfigError(f"{where}: {exc}") from exc
            if not finite.all():
                raise DatasetError(f"{where}: stored raw row has non-finite live taxels")
            live = values[0][normaliser.live_mask]
            series.append(live[None])
            contact[0] += float(live.sum(dtype=np.float64))
            contact[1] = max(contact[1], float(live.max(initial=0.0)))
            if self.store_maps:   # else readers render the map from the raw rows under the new calibration
                out[tactile_member(hand)] = MEMBER_CODECS["exr"][0](raster.render(values)[0], self.settings,
                                                                    f"{where} map")
            if bend_member(hand) in members:
                out[bend_member(hand)] = MEMBER_CODECS["npy"][0](raster.bend_vector(values)[0], self.settings,
                                                                 f"{where} bend")
        return out

    def record(self, record: dict) -> dict:
        eid = record["episode_id"]
        if eid not in self.plan.changes:
            return record
        state = self.state.pop(eid, None) or self._start(eid)
        record = dict(record)
        n = int(record["num_frames"])
        stats = dict(record.get("stats", {}))
        mean, peak = dict(stats.get("mean_contact", {})), dict(stats.get("max_contact", {}))
        calibration, fits = dict(record.get("calibration", {})), dict(record.get("calibration_fit", {}))
        paired = int(stats.get("frames_kept", n))   # frames with maps (RGB-only samples have none)
        health = dict(record.get("taxel_health", {}))
        for hand, (normaliser, _, (total, top), series) in state.items():
            health[hand] = record_entry(series, self.layouts[record["layouts"][hand]])
            mean[hand] = total / (paired * int(normaliser.live_mask.sum()))
            peak[hand] = top
            calibration[hand] = self.plan.changes[eid][hand][1]
            fits.pop(hand, None)
            if fit_record(normaliser):
                fits[hand] = fit_record(normaliser)
        record["stats"] = {**stats, "mean_contact": mean, "max_contact": peak}
        record["taxel_health"] = health
        record["calibration"] = calibration
        record.pop("calibration_fit", None)
        record.pop("calibration_fit_sha256", None)
        if fits:
            record["calibration_fit"] = fits
            record["calibration_fit_sha256"] = fit_digests(fits)
        record["taxels_sha256"] = {**record.get("taxels_sha256", {}),
                                   **{hand: taxel_digest(series) for hand, (_, _, _, series) in state.items()}}
        changed = ", ".join(f"{h} {old or '(none)'} -> {new}" for h, (old, new) in self.plan.changes[eid].items())
        record["notes"] = list(record.get("notes", [])) + [
            f"renormalised from stored raw rows (version {self.snap.version}): calibration {changed}",
            *self.plan.warnings.get(eid, [])]
        return record


def renormalise(root, normalising: NormaliseSettings, patterns: list[str] | None, dry_run: bool, force: bool,
                command: str) -> tuple[RenormalisePlan, dict | None]:
    """Plan (and unless `dry_run`, write) a version whose maps follow the calibrations of `normalising` (a pipeline's NormaliseSettings)."""
    with NewVersion(root, command) as nv, tempfile.TemporaryDirectory(prefix="htdata-renormalise-") as tmp:
        # the version's layouts, loaded once; `normalising` (after the glove rests below) resolves each once,
        # and the plan, its warnings and the rewrite read those
        layouts = dataset_layouts(nv.parent)
        # the glove's own rest where the settings leave a raw-count glove to the default (a dry run writes
        # its reference files to a temporary folder, not into the dataset)
        normalising, rests = dataset_glove_rests(Path(tmp) if dry_run else nv.root, nv.parent, layouts,
                                                 nv.reader(), normalising)
        plan = plan_renormalise(nv.parent, layouts, normalising, patterns, force)
        plan.notes = [r.note([normalising.name]) for r in rests]
        if not plan.changes:
            return plan, None
        rest_level_warnings(nv.reader(), nv.parent, layouts, normalising, plan)
        if dry_run:
            return plan, None
        return plan, _write(nv, layouts, normalising, plan)


def _write(nv: NewVersion, layouts: dict[str, Layout], normalising: NormaliseSettings,
           plan: RenormalisePlan) -> dict:
    """Re-pack the units holding changed episodes under the new calibrations and commit them (the manifest);
    a failure (bad settings for some frame) leaves no shard of this attempt behind (NewVersion)."""
    rewrite = Recalibration(nv.reader(), nv.parent, layouts, normalising, plan)
    parts = nv.carry_or_repack(lambda part: [KeptEpisode.whole(rec) for rec in part.episodes]
                               if part.unit in plan.repacked_units else part, rewrite=rewrite)
    return nv.commit(parts, {"calibrations": plan.calibrations})
