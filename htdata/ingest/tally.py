"""What one episode's ingest learned, for its record in episodes.jsonl (filled while its frames are read: ingest/episode.py).

`EpisodeTally` accumulates while htdata.ingest.episode yields the frames:
the sync report, frames dropped from pairing and RGB-only samples kept,
contact sums, out-of-range counts, notes, fps, the normalisers (the
episode's calibration) and each hand's live-taxel series, classified once
at the end for the record's `taxel_health` (htdata.glove.health; the exact
normalised values, before the map codec). `record()` builds the episode record once the
generator is exhausted.
"""

from __future__ import annotations

import numpy as np

from htdata.glove.activity import CellActivity, unmapped_moving
from htdata.glove.calibration import calibration_id, fit_digests, fit_record, taxel_digest
from htdata.glove.health import record_entry
from htdata.glove.layouts import Layout
from htdata.glove.restlevel import rest_level_warning
from htdata.source.sync import SyncResult


class EpisodeTally:
    """What reading an episode's frames learns about it (`EpisodeStream.finished_tally()`); `record()` is its record."""

    def __init__(self):
        self.ref = None
        self.hands: list[str] = []
        self.layouts: dict[str, Layout] = {}
        self.sync: SyncResult | None = None
        self.dropped: list[tuple[int, str]] = []     # (rgb index, reason)
        self.frames = 0
        self.contact_sum: dict[str, float] = {}
        self.contact_max: dict[str, float] = {}
        self.notes: list[str] = []
        self.fps: float | None = None
        self.has_video = True
        # hand -> [below taxel values, above taxel values, frames with any] over the synchronised frames
        self.out_of_range: dict[str, list[int]] = {}
        self.raw_max: dict[str, float] = {}
        self.oor_policy = None
        self.normalisers: dict = {}    # hand -> Normaliser (its settings and fitted arrays: the calibration)
        self.live_series: dict[str, list[np.ndarray]] = {}   # hand -> (T, L) chunks for taxel health
        self.paired = 0                # frames with tactile (tally.frames also counts RGB-only ones)
        self.rgb_only: dict[str, int] = {}   # reason -> RGB-only samples kept (htdata.ingest.fullrate)
        self.raw_rows_dropped: dict[str, int] = {}   # hand -> unpaired rows beyond every sample's raw span
        self.raw_span_ms: dict[str, float] = {}
        self.raw_rows_capped: dict[str, tuple[int, int]] = {}   # hand -> (rows over the per-sample cap, the cap)
        self.activity: dict[str, CellActivity] = {}   # hand -> raw activity of every cell (htdata.glove.activity)

    def start(self, ref, hands: list[str], layouts: dict[str, Layout], oor_policy=None) -> None:
        self.ref, self.hands, self.layouts = ref, hands, layouts
        self.contact_sum = {h: 0.0 for h in hands}
        self.contact_max = {h: 0.0 for h in hands}
        self.out_of_range = {h: [0, 0, 0] for h in hands}
        self.oor_policy = oor_policy
        self.activity = {h: CellActivity(layouts[h].grid) for h in hands}

    def add_raw(self, hand: str, raw: np.ndarray) -> None:
        """The paired raw rows of one chunk, in time order: activity of every cell (unmapped moving cells)."""
        self.activity[hand].add(raw)

    def unmapped_moving_record(self) -> dict:
        """{hand: MovingCells.record()} for hands with cells outside every block that move ({} when none)."""
        out = {}
        for h in self.hands:
            if h in self.activity:
                found = unmapped_moving(self.activity[h], self.layouts[h])
                if len(found):
                    out[h] = found.record()
        return out

    def add_out_of_range(self, hand: str, below: np.ndarray, above: np.ndarray) -> np.ndarray:
        """Count one chunk's out-of-range taxels; returns the per-frame mask of frames holding any."""
        bad = (below > 0) | (above > 0)
        c = self.out_of_range[hand]
        c[0] += int(below.sum())
        c[1] += int(above.sum())
        c[2] += int(bad.sum())
        return bad

    def out_of_range_record(self) -> dict:
        """{hand: {"below", "above", "frames"}} for hands with any out-of-range value ({} when clean)."""
        return {h: {"below": c[0], "above": c[1], "frames": c[2]} for h, c in self.out_of_range.items() if c[2]}

    def _out_of_range_notes(self) -> list[str]:
        if self.oor_policy is None or self.sync is None:
            return []
        total = max(int(self.sync.rgb_index.size), 1)
        notes = []
        for h, c in self.out_of_range_record().items():
            share = c["frames"] / total
            if self.oor_policy.policy == "clip" and share > self.oor_policy.warn_share:
                notes.append(f"warning: {h} hand: {c['frames']} of {total} frames ({share:.1%}) hold raw values "
                             f"outside [0, {self.raw_max.get(h, '?'):g}] ({c['below']} below, {c['above']} above): "
                             f"clipped (pipeline [normalise] out_of_range = \"clip\")"
                             + ("; max_value is the glove's FULL-SCALE raw value (its ADC top), not the range above "
                                "its rest level" if c["above"] and share >= 0.5 else ""))
        return notes

    def add_contact(self, hand: str, live: np.ndarray) -> None:
        self.live_series.setdefault(hand, []).append(np.asarray(live, np.float32))
        self.contact_sum[hand] += float(live.sum(dtype=np.float64))
        self.contact_max[hand] = max(self.contact_max[hand], float(live.max(initial=0.0)))

    def count_row_plans(self, plans: dict) -> None:
        """What the hands' RowPlans (htdata/ingest/fullrate.py) left out: rows beyond the span, rows over the cap."""
        self.raw_rows_dropped = {h: plan.dropped for h, plan in plans.items() if plan.dropped}
        self.raw_rows_capped = {h: (plan.capped, plan.cap) for h, plan in plans.items() if plan.capped}
        self.raw_span_ms = {h: plan.span_ns / 1e6 for h, plan in plans.items()}

    def finish(self, streams) -> None:
        ref = self.ref
        self.notes = list(streams.notes) + list(self.sync.report.get("warnings", [])) + self._out_of_range_notes()
        for h in self.hands:     # a raw-count glove's rest read as pressure (baseline "none"): say so
            if h in self.activity and h in self.normalisers and self.activity[h].frames:
                a = self.activity[h]
                line = rest_level_warning(h, self.layouts[h], self.normalisers[h].cfg, a.lo, a.hi)
                if line:
                    self.notes.append(line)
        for h, n in sorted(self.raw_rows_dropped.items()):
            self.notes.append(f"{h} hand: {n} glove rows more than {self.raw_span_ms[h]:g} ms from every video "
                              f"frame (after the last, before the first, or in a gap) dropped: no sample stores them")
        for h, (n, cap) in sorted(self.raw_rows_capped.items()):
            self.notes.append(f"warning: {h} hand: {n} glove rows dropped over the {cap} rows one sample may "
                              f"store (htdata/ingest/fullrate.py raw_row_cap: rows packed closer than the glove's "
                              f"rate, or a stuck clock)")
        self.fps = _fps(streams.rgb_timestamps_ns)
        self.has_video = streams.has_video
        if self.fps is None:
            self.fps = float(ref.extra.get("fps", 30.0)) if isinstance(ref.extra, dict) else 30.0
            self.notes.append(f"fps unknown (single RGB timestamp): recorded as {self.fps}")

    def dropped_sorted(self) -> list[tuple[int, str]]:
        return sorted(self.dropped)

    def record(self) -> dict:
        """The episode's line in episodes.jsonl (schemas/episode.schema.json)."""
        ref, hands, n = self.ref, self.hands, self.frames
        reasons: dict[str, int] = {}
        for _, r in self.dropped:
            reasons[r] = reasons.get(r, 0) + 1
        record = {
            "episode_id": ref.episode_id, "source": ref.source, "source_ref": ref.source_ref,
            "input_fingerprint": ref.fingerprint, "task": ref.task, "scene": ref.scene, "hands": hands,
            "layouts": {h: self.layouts[h].layout_id for h in hands},
            "num_frames": n, "fps": self.fps,
            "stats": {"mean_contact": {h: self.contact_sum[h] / (self.paired * self.layouts[h].num_live)
                                       for h in hands},
                      "max_contact": self.contact_max, "frames_in": int(self.sync.report["n_rgb"]),
                      "frames_kept": self.paired, "frames_dropped": len(self.dropped),
                      "frames_rgb_only": n - self.paired},
            "sync": self.sync.report, "dropped_frames": reasons, "notes": self.notes,
        }
        if not self.has_video:
            record["tactile_only"] = True     # a glove-only recording: no RGB member in any sample
        if self.rgb_only:   # RGB frames kept without tactile (dropped from pairing), by reason
            record["rgb_only_frames"] = dict(sorted(self.rgb_only.items()))
        if isinstance(ref.extra, dict) and ref.extra.get("source_split"):
            record["source_split"] = str(ref.extra["source_split"])
        # Added only when there is something to say: a clean episode's record keeps its exact bytes.
        if self.out_of_range_record():
            record["out_of_range"] = self.out_of_range_record()
        if self.raw_rows_dropped:
            record["raw_rows_dropped"] = dict(sorted(self.raw_rows_dropped.items()))
        if self.raw_rows_capped:
            record["raw_rows_capped"] = {h: n for h, (n, _) in sorted(self.raw_rows_capped.items())}
        if self.unmapped_moving_record():   # live cells the layout leaves out (htdata.glove.activity)
            record["unmapped_moving"] = self.unmapped_moving_record()
        if isinstance(ref.extra, dict) and ref.extra.get("hands_excluded"):
            record["hands_excluded"] = dict(sorted(ref.extra["hands_excluded"].items()))
        record["taxel_health"] = {h: record_entry(self.live_series.get(h, []), self.layouts[h]) for h in hands}
        record["calibration"] = {h: calibration_id(self.layouts[h].layout_id, self.normalisers[h].cfg) for h in hands}
        fits = {h: fit_record(self.normalisers[h]) for h in hands}
        if any(fits.values()):
            record["calibration_fit"] = {h: f for h, f in fits.items() if f}
            record["calibration_fit_sha256"] = fit_digests(record["calibration_fit"])
        # what every map of the hand is rasterised from: validate --deep re-derives it from the raw rows
        record["taxels_sha256"] = {h: taxel_digest(self.live_series.get(h, [])) for h in hands}
        return record


def _fps(rgb_ts: np.ndarray) -> float | None:
    d = np.diff(np.unique(np.asarray(rgb_ts, dtype=np.int64)))
    return float(1e9 / np.median(d)) if d.size else None
