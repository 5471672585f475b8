"""`htdata trim DATASET --idle`: drop the head and tail of each episode where no hand touches anything.

A frame is in contact when any hand is, by the hand's contact rule
(htdata/glove/contact.py: from its calibration, the per-frame contact of the stats
cache, htdata/inspect/stats.py, so a dataset whose stats are cached is planned
without reading a shard). `min_contact` = X applies the old rule instead:
any taxel of any hand above X (the per-frame maxima of the same cache). Each episode keeps
its frames from the first contact minus `keep_margin_s` to the last contact
plus `keep_margin_s` (frames = round(seconds x the episode's fps)). Idle
stretches in the middle stay: a trim keeps one contiguous range. An episode
with no contact at all is left as it is and listed ("remove it with htdata
rm" if it should go): trimming it to nothing is not a trim. A frame whose
map could not be read (NaN) counts as contact, so it is never dropped
silently. All trims go into ONE new version through curate's
plan_edit / apply_edit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from htdata.curate import edit as curate_edit
from htdata.errors import ArgumentError
from htdata.glove.contact import THRESHOLD
from htdata.inspect.stats import default_cache_dir, episode_stats
from htdata.read.reader import DatasetReader
from htdata.write.newversion import NewVersion


@dataclass
class IdleConfig:
    min_contact: float | None = None     # None: each hand's contact rule; X: any taxel above X (the old rule)
    keep_margin_s: float = 0.5

    def validate(self) -> None:
        if self.min_contact is not None and not 0.0 <= self.min_contact < 1.0:
            raise ArgumentError(f"--min-contact must be in [0, 1), got {self.min_contact}")
        if self.keep_margin_s < 0:
            raise ArgumentError(f"--keep-margin must be >= 0 seconds, got {self.keep_margin_s}")


@dataclass
class IdleCut:
    """What --idle does to one episode: keep `keep` of `frames` (None: untouched, see `reason`)."""
    episode: str
    frames: int
    keep: range | None
    reason: str = ""

    @property
    def dropped(self) -> int:
        return 0 if self.keep is None else self.frames - len(self.keep)

    def line(self, dry_run: bool) -> str:
        if self.keep is None:
            return f"episode {self.episode}: {self.reason}"
        head, tail = self.keep.start, self.frames - self.keep.stop
        would = "would drop" if dry_run else "dropped"
        return (f"episode {self.episode}: {would} {head} head + {tail} tail idle frames, keep "
                f"{self.keep.start}:{self.keep.stop} of {self.frames}")


def contact_frames(stats: dict, min_contact: float | None) -> np.ndarray:
    """(frames,) bool: any hand in contact (its rule, or a taxel above `min_contact` when given);
    frames with no readable map count as contact."""
    n = int(stats["frames"])
    readable = np.zeros(n, bool)
    contact = np.zeros(n, bool)
    for h in stats["hands"].values():
        idx = np.asarray(h["frame_index"], np.int64)
        readable[idx] = True
        if min_contact is None and "frame_contact" in h:
            contact[idx] |= np.asarray(h["frame_contact"], bool)
        else:   # the old rule (asked for, or stats computed before the contact rules)
            level = THRESHOLD if min_contact is None else min_contact
            contact[idx] |= np.asarray(h["frame_max"], np.float64) > level
    return contact | ~readable


def plan_cut(record: dict, stats: dict, cfg: IdleConfig) -> IdleCut:
    n = int(stats["frames"])
    eid = record["episode_id"]
    hit = np.flatnonzero(contact_frames(stats, cfg.min_contact))
    if hit.size == 0:
        rule = "by its contact rule" if cfg.min_contact is None else f"above {cfg.min_contact}"
        return IdleCut(eid, n, None, f"no contact {rule} in any of its {n} frames: left as "
                                     f"it is (remove it with htdata rm if it should go)")
    margin = int(round(cfg.keep_margin_s * float(record.get("fps") or 0.0)))
    keep = range(max(0, int(hit[0]) - margin), min(n, int(hit[-1]) + 1 + margin))
    if len(keep) == n:
        return IdleCut(eid, n, None, "no idle head or tail beyond the margin")
    return IdleCut(eid, n, keep)


def plan_idle(reader: DatasetReader, cfg: IdleConfig, cache_dir="default") -> list[IdleCut]:
    """One IdleCut per episode of the reader's version (stats computed for uncached episodes)."""
    cfg.validate()
    cache = default_cache_dir(reader.root) if cache_dir == "default" else cache_dir
    per_episode, _ = episode_stats(reader, cache_dir=cache)
    return [plan_cut(rec, st, cfg) for rec, st in zip(reader.episodes, per_episode)]


def trim_idle(root, cfg: IdleConfig, dry_run: bool, command: str, cache_dir="default"
              ) -> tuple[list[IdleCut], curate_edit.Edit | None, dict | None]:
    """(cuts, edit or None when nothing is idle, manifest of the new version or None)."""
    with NewVersion(root, command) as nv:
        cuts = plan_idle(nv.reader(), cfg, cache_dir)
        trims = {c.episode: c.keep for c in cuts if c.keep is not None}
        if not trims:
            return cuts, None, None
        edit, plan = curate_edit.plan_edit(nv.parent, [], trims)
        return cuts, edit, None if dry_run else curate_edit.apply_edit(nv, plan)
