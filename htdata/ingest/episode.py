"""One episode as a stream of canonical frames: the data path every consumer shares.

`episode_frames(ref, cfg, adapter, tally)` opens the episode, pairs the
clocks (sync.py), reads tactile rows `chunk_frames` at a time, checks their
shape against the planned layout, normalises, drops frames with non-finite
live taxels, rasterises and yields one `Frame` per kept frame (meta, RGB,
maps, bend vectors), in frame order. Raw values outside the layout's range
[0, max_value] are counted per hand and handled by the pipeline's
`[normalise] out_of_range` policy (clip / drop_frame / fail). It encodes
and writes nothing: the ingest unit encodes each frame with `htdata.format.encode_sample`, the
benchmarks (htdata/benchmarks/sources.py) keep the maps. What the episode
record needs (sync report, dropped frames, contact stats, notes, fps) is
accumulated in the caller's `EpisodeTally`, complete once the generator is
exhausted. Memory stays flat in episode length.

Error policy: everything raised while a frame is being processed leaves the
generator as an `EpisodeError` naming file, episode and that frame
(`frame_errors`); the caller decides what a failed episode means (the
ingest unit records it and goes on with the next episode).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from htdata.errors import EpisodeError
from htdata.format import HANDS
from htdata.ingest.timing import StageClock
from htdata.layouts import Layout, load_layout
from htdata.normalise import Normaliser
from htdata.pipeline import PipelineConfig
from htdata.rasterise import Rasteriser
from htdata.rgb import to_square_224
from htdata.shardio import sample_key
from htdata.sync import SyncResult, pair


@dataclass
class Frame:
    """What one kept frame's sample needs, decoded (see htdata.format for the sample dict)."""
    key: str                       # sample key (episode id + frame index)
    source_frame: int              # RGB frame index in the source
    meta: dict                     # the sample's JSON member
    rgb: np.ndarray | None         # (size,size,3) uint8 RGB; None when RGB was not asked for
    maps: dict[str, np.ndarray]    # hand -> (224,224) float32 in [0,1]
    bends: dict[str, np.ndarray] = field(default_factory=dict)   # hand -> (K,) float32

    def sample(self) -> dict:
        return {"meta": self.meta, "rgb": self.rgb, "tactile": self.maps, "bend": self.bends}


@contextmanager
def frame_errors(ref, frame: int | None):
    """Whatever is raised inside names this episode and `frame` (an EpisodeError keeps its own frame)."""
    try:
        yield
    except EpisodeError as exc:
        named = exc.at_frame(frame)
        if named is exc:
            raise
        raise named from exc
    except Exception as exc:
        raise EpisodeError(ref, frame, f"{type(exc).__name__}: {exc}") from exc


_RASTERS: dict[tuple[int, str], tuple[Layout, Rasteriser]] = {}


def rasteriser_for(layout: Layout, mode: str) -> Rasteriser:
    """One Rasteriser per (layout, mode) per process; layouts are cached per file version by load_layout."""
    key = (id(layout), mode)
    if key not in _RASTERS:   # the layout is kept in the value, so its id is never reused
        _RASTERS[key] = (layout, Rasteriser(layout, mode=mode))
    return _RASTERS[key][1]


def planned_layouts(ref, hands: list[str]) -> dict[str, Layout]:
    """The layouts planning resolved for this episode (`ref.layout_files`, see htdata.ingest.plan)."""
    missing = [h for h in hands if h not in ref.layout_files]
    if missing:
        raise ValueError(f"episode {ref.episode_id}: no resolved layout for hand(s) {missing}; "
                         f"plan the episode first (htdata.ingest.plan.resolve_layouts)")
    return {h: load_layout(ref.layout_files[h]) for h in hands}


class EpisodeTally:
    """What `episode_frames` learns about an episode while yielding it; read `record()` once exhausted."""

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
        # hand -> [below taxel values, above taxel values, frames with any] over the synchronised frames
        self.out_of_range: dict[str, list[int]] = {}
        self.raw_max: dict[str, float] = {}
        self.oor_policy = None

    def start(self, ref, hands: list[str], layouts: dict[str, Layout], oor_policy=None) -> None:
        self.ref, self.hands, self.layouts = ref, hands, layouts
        self.contact_sum = {h: 0.0 for h in hands}
        self.contact_max = {h: 0.0 for h in hands}
        self.out_of_range = {h: [0, 0, 0] for h in hands}
        self.oor_policy = oor_policy

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
                             f"clipped (pipeline [normalise] out_of_range = \"clip\")")
        return notes

    def add_contact(self, hand: str, live: np.ndarray) -> None:
        self.contact_sum[hand] += float(live.sum(dtype=np.float64))
        self.contact_max[hand] = max(self.contact_max[hand], float(live.max(initial=0.0)))

    def finish(self, streams) -> None:
        ref = self.ref
        self.notes = list(streams.notes) + list(self.sync.report.get("warnings", [])) + self._out_of_range_notes()
        self.fps = _fps(streams.rgb_timestamps_ns)
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
            "stats": {"mean_contact": {h: self.contact_sum[h] / (n * self.layouts[h].num_live) for h in hands},
                      "max_contact": self.contact_max, "frames_in": int(self.sync.report["n_rgb"]),
                      "frames_kept": n, "frames_dropped": len(self.dropped)},
            "sync": self.sync.report, "dropped_frames": reasons, "notes": self.notes,
        }
        if isinstance(ref.extra, dict) and ref.extra.get("source_split"):
            record["source_split"] = str(ref.extra["source_split"])
        # Added only when there is something to say: a clean episode's record keeps its exact bytes.
        if self.out_of_range_record():
            record["out_of_range"] = self.out_of_range_record()
        if isinstance(ref.extra, dict) and ref.extra.get("hands_excluded"):
            record["hands_excluded"] = dict(sorted(ref.extra["hands_excluded"].items()))
        return record


def _fps(rgb_ts: np.ndarray) -> float | None:
    d = np.diff(np.unique(np.asarray(rgb_ts, dtype=np.int64)))
    return float(1e9 / np.median(d)) if d.size else None


class RgbFetcher:
    """Hand out RGB frames by index while reading the video once, in file order.

    Frames wanted later (only when timestamps were out of file order) wait as
    resized arrays; unwanted frames are skipped without resizing.
    """

    def __init__(self, ref, frames, wanted: np.ndarray, resize, clock: StageClock):
        self.ref = ref
        self.frames = iter(frames)
        self.wanted = set(int(i) for i in wanted)
        self.resize = resize
        self.clock = clock
        self.pending: dict[int, np.ndarray] = {}

    def get(self, index: int) -> np.ndarray:
        index = int(index)
        while index not in self.pending:
            try:
                with self.clock.stage("decode"):
                    i, frame = next(self.frames)
            except StopIteration:
                raise EpisodeError(self.ref, index, "RGB stream ended before this frame") from None
            i = int(i)
            if i in self.wanted:
                with self.clock.stage("resize"):
                    self.pending[i] = self.resize(frame, i)
        self.wanted.discard(index)
        return self.pending.pop(index)

    def discard(self, index: int) -> None:
        self.wanted.discard(int(index))
        self.pending.pop(int(index), None)


def _pair_clocks(ref, cfg: PipelineConfig, streams, hands: list[str]) -> SyncResult:
    missing = [h for h in hands if h not in streams.tactile_timestamps_ns]
    if missing:
        raise EpisodeError(ref, None, f"no tactile stream for hand(s) {missing}")
    try:
        sync = pair(streams.rgb_timestamps_ns, {h: streams.tactile_timestamps_ns[h] for h in hands},
                    cfg.sync.max_skew_ns, cfg.sync.policy)
    except ValueError as e:
        raise EpisodeError(ref, None, f"sync: {e}") from e
    if sync.rgb_index.size == 0:
        raise EpisodeError(ref, None, f"no RGB frame has tactile data within {cfg.sync.max_skew_ms} ms "
                           f"({sync.report['drop_reasons']})")
    return sync


def _read_chunk(ref, streams, tally: EpisodeTally, normalisers: dict, start: int, stop: int,
                clock: StageClock) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Normalised values of every hand for sync rows [start, stop) and the mask of frames kept."""
    sync = tally.sync
    rgb_idx = sync.rgb_index[start:stop]
    ok = np.ones(stop - start, dtype=bool)
    values = {}
    for h in tally.hands:
        layout = tally.layouts[h]
        uniq, inverse = np.unique(sync.tactile_index[h][start:stop], return_inverse=True)  # increasing rows
        with clock.stage("decode"):
            raw = np.asarray(streams.read_tactile(h, uniq))
        if raw.ndim != 3 or raw.shape[1:] != tuple(layout.grid) or raw.shape[0] != uniq.size:
            raise EpisodeError(ref, int(rgb_idx[0]), f"{h} tactile rows have shape {raw.shape}, expected "
                               f"({uniq.size}, {layout.grid[0]}, {layout.grid[1]}) for layout {layout.layout_id}")
        raw = raw[inverse.reshape(-1)]
        with clock.stage("normalise"):
            if start == 0:
                normalisers[h].fit_baseline(raw)
            v, finite = normalisers[h].apply(raw)
            below, above = normalisers[h].out_of_range(raw)
        for j in np.flatnonzero(ok & ~finite):
            tally.dropped.append((int(rgb_idx[j]), f"nonfinite_tactile:{h}"))
        ok &= finite
        ok &= _out_of_range_policy(ref, tally, h, normalisers[h], raw, below, above, rgb_idx, ok)
        values[h] = v
    return values, ok


def _out_of_range_policy(ref, tally: EpisodeTally, hand: str, normaliser, raw, below, above, rgb_idx,
                         ok: np.ndarray) -> np.ndarray:
    """Count a chunk's out-of-range raw values and apply the policy; returns the mask of frames that stay."""
    bad = tally.add_out_of_range(hand, below, above)
    tally.raw_max[hand] = float(normaliser.cfg.max_value)
    policy = tally.oor_policy.policy if tally.oor_policy is not None else "clip"
    if not bad.any() or policy == "clip":
        return np.ones_like(ok)
    if policy == "fail":
        j = int(np.flatnonzero(bad)[0])
        live = raw[j][normaliser.live_mask]
        with np.errstate(invalid="ignore"):
            worst = float(live[(live < 0) | (live > np.float32(normaliser.cfg.max_value))][0])
        raise EpisodeError(ref, int(rgb_idx[j]), f"{hand} hand raw value {worst:g} outside [0, "
                           f"{normaliser.cfg.max_value:g}] (layout {normaliser.layout_id}; {int(below[j])} taxels "
                           f"below, {int(above[j])} above); pipeline [normalise] out_of_range = \"fail\"")
    for j in np.flatnonzero(ok & bad):   # drop_frame
        tally.dropped.append((int(rgb_idx[j]), f"out_of_range:{hand}"))
    return ~bad


def episode_frames(ref, cfg: PipelineConfig, adapter, tally: EpisodeTally, clock: StageClock | None = None,
                   with_rgb: bool = True) -> Iterator[Frame]:
    """Yield the kept frames of one planned episode (see the module docstring); raise EpisodeError on failure.

    `ref` must come from planning (layouts resolved). `with_rgb=False` skips
    the RGB decode (Frame.rgb is None): the benchmarks that only need maps.
    Per chunk: the tactile rows are read, normalised and rasterised first,
    then the chunk's RGB frames are fetched in order and yielded.
    """
    clock = clock or StageClock()
    hands = [h for h in HANDS if h in ref.hands]
    tally.start(ref, hands, planned_layouts(ref, hands), cfg.out_of_range)
    layouts = tally.layouts
    with clock.stage("decode"):
        opened = adapter.open(ref, cfg.adapter.params)
    with opened as streams:
        sync = tally.sync = _pair_clocks(ref, cfg, streams, hands)
        tally.dropped = list(sync.dropped)
        normalisers = {h: Normaliser(cfg.normalise_for(layouts[h]), layouts[h]) for h in hands}
        rasters = {h: rasteriser_for(layouts[h], cfg.tactile.raster_mode) for h in hands}
        keep_bend = {h: cfg.tactile.keep_bend and len(layouts[h].bend_cells) > 0 for h in hands}
        rgb_cfg = cfg.rgb

        def resize(frame, i):
            return to_square_224(frame, rgb_cfg.size, rgb_cfg.crop, rgb_cfg.interpolation,
                                 where=f"{ref.source_ref} [{ref.episode_id}] frame {i}")

        fetcher = RgbFetcher(ref, streams.iter_rgb(), sync.rgb_index, resize, clock) if with_rgb else None
        hands_flags = {h: h in hands for h in HANDS}
        total = int(sync.rgb_index.size)
        chunk = cfg.tactile.chunk_frames
        for start in range(0, total, chunk):
            stop = min(total, start + chunk)
            rgb_idx = sync.rgb_index[start:stop]
            with frame_errors(ref, int(rgb_idx[0])):
                values, ok = _read_chunk(ref, streams, tally, normalisers, start, stop, clock)
                if fetcher is not None:
                    for j in np.flatnonzero(~ok):
                        fetcher.discard(rgb_idx[j])
                keep = np.flatnonzero(ok)
                maps, bends = {}, {}
                with clock.stage("rasterise"):
                    for h in hands if keep.size else ():
                        v = values[h][keep]
                        maps[h] = rasters[h].render(v)
                        tally.add_contact(h, v[:, layouts[h].live_mask])
                        if keep_bend[h]:
                            bends[h] = rasters[h].bend_vector(v)
            for n, j in enumerate(keep):
                i = int(rgb_idx[j])
                k = start + int(j)
                with frame_errors(ref, i):
                    rgb = fetcher.get(i) if fetcher is not None else None  # timed inside as decode + resize
                key = sample_key(ref.episode_id, tally.frames)
                meta = {"key": key, "episode_id": ref.episode_id, "frame_index": tally.frames,
                        "source_frame": i, "t_rgb_ns": int(sync.t_rgb_ns[k]),
                        "t_tactile_ns": {h: int(sync.t_tactile_ns[h][k]) for h in hands},
                        "sync_offset_ns": {h: int(sync.skew_ns[h][k]) for h in hands},
                        "hands": hands_flags}
                tally.frames += 1
                yield Frame(key=key, source_frame=i, meta=meta, rgb=rgb, maps={h: maps[h][n] for h in hands},
                            bends={h: b[n] for h, b in bends.items()})
        if tally.frames == 0:
            why = ("non-finite or out-of-range (out_of_range = \"drop_frame\")"
                   if any(r.startswith("out_of_range:") for _, r in tally.dropped) else "non-finite")
            raise EpisodeError(ref, None, f"no frame left: all {total} synchronised frames had {why} "
                               f"tactile values")
        tally.finish(streams)
