"""One episode as a stream of canonical frames: the data path every consumer shares.

`EpisodeStream(ref, cfg, adapter)` is the face: iterate it once for the
frames, then `finished_tally()` is what reading them found (the episode
record's contents), refused until every frame was read. Underneath,
`episode_frames(ref, cfg, adapter, tally)` opens the episode, pairs the
clocks (sync.py), reads tactile rows `chunk_frames` at a time, checks their
shape against the planned layout, normalises, drops frames with non-finite
live taxels, rasterises and yields one `Frame` per kept frame (meta, RGB,
maps, bend vectors, the raw glove rows each sample stores), in time order.
Every recorded frame stays (htdata/ingest/fullrate.py): unpaired glove rows
ride in the raw members of the samples around them, RGB frames without
tactile become RGB-only samples, and a glove-only recording (no video)
becomes tactile-only samples on its first hand's clock. Raw values outside the layout's range
[0, max_value] are counted per hand and handled by the pipeline's
`[normalise] out_of_range` policy (clip / drop_frame / fail). It encodes
and writes nothing: the ingest unit encodes each frame with `htdata.format.table.encode_sample`, the
benchmarks (htdata/benchmarks/sources.py) keep the maps. What the episode
record needs (sync report, dropped frames, contact stats, notes, fps) is
accumulated in an `EpisodeTally`, complete once the generator is exhausted
(EpisodeStream holds it and says so). Memory stays flat in episode length, except for the live-taxel
series the tally keeps for the record's taxel health (4 bytes per live taxel
and frame: ~0.7 KB a frame for a 169-taxel glove, ~25 MB for an hour at 30 fps).

Error policy: everything raised while a frame is being processed leaves the
generator as an `EpisodeError` naming file, episode and that frame
(`frame_errors`, htdata/ingest/frame.py with `Frame`). The RGB side (the video
read once in file order, RGB-only frames) is htdata/ingest/rgbframes.py.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from htdata.errors import EpisodeError
from htdata.format.shardio import sample_key
from htdata.format.table import HANDS
from htdata.glove.layouts import Layout, load_layout
from htdata.glove.normalise import Normaliser
from htdata.glove.rasterise import Rasteriser
from htdata.ingest.chunk import frame_raw_rows, read_chunk
from htdata.ingest.frame import Frame, frame_errors
from htdata.ingest.fullrate import FrameQueue, RowPlan
from htdata.ingest.pipeline import PipelineConfig
from htdata.ingest.rgbframes import RgbOnlyFrames, rgb_source
from htdata.ingest.tally import EpisodeTally
from htdata.ingest.timing import StageClock
from htdata.source.lag import episode_lag
from htdata.source.sync import SyncResult, pair

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


def _pair_clocks(ref, cfg: PipelineConfig, streams, hands: list[str], adapter) -> SyncResult:
    missing = [h for h in hands if h not in streams.tactile_timestamps_ns]
    if missing:
        raise EpisodeError(ref, None, f"no tactile stream for hand(s) {missing}")
    # [sync] lag: None for "none"; estimates open a 2nd stream
    lag = episode_lag(ref, adapter, cfg.adapter.params, cfg.normalise_settings(), cfg.sync, hands)
    try:
        sync = pair(streams.rgb_timestamps_ns, {h: streams.tactile_timestamps_ns[h] for h in hands},
                    cfg.sync.max_skew_ns, cfg.sync.policy, lag=lag)
    except ValueError as e:
        raise EpisodeError(ref, None, f"sync: {e}") from e
    if sync.rgb_index.size == 0:
        raise EpisodeError(ref, None, f"no RGB frame has tactile data within {cfg.sync.max_skew_ms} ms "
                           f"({sync.report['drop_reasons']})")
    return sync


def _fit_episode_baselines(ref, cfg: PipelineConfig, adapter, streams, sync, normalisers: dict) -> None:
    """Fit the baselines chosen by activity (quietest / percentile / drift) on the hand's paired rows.

    They need the whole episode before its first frame is normalised: the
    rows are read through a second opening of the source (the main pass stays
    one forward pass, as streamed sources need), at the glove's own frame rate.
    """
    wanted = [h for h, n in normalisers.items() if n.cfg.per_episode]
    if not wanted:
        return
    with adapter.open(ref, cfg.adapter.params) as again:
        for h in wanted:
            rows = np.unique(sync.tactile_index[h])
            ts = np.asarray(streams.tactile_timestamps_ns[h], np.int64)[rows]
            step = np.median(np.diff(ts)) if ts.size > 1 else 0
            fps = 1e9 / step if step > 0 else 30.0
            try:
                normalisers[h].fit_episode(np.asarray(again.read_tactile(h, rows), np.float32), fps, rows)
            except ValueError as exc:
                raise EpisodeError(ref, None, f"{h} hand baseline {normalisers[h].cfg.baseline!r}: {exc}") from exc


def _kept_values(values: dict, keep: np.ndarray, rasters: dict, keep_bend: dict, tally: EpisodeTally,
                 map_dtype) -> tuple[dict, dict]:
    """(bend vectors, `Rasteriser.frames` of `map_dtype` or {} for None) of a chunk's kept frames, per hand;
    their contact goes into the tally.

    Maps are rendered one frame at a time as each frame leaves (`_frame_maps`, from the chunk's
    `Rasteriser.frames`): a chunk of rendered maps is 200 KiB per frame and hand, and frames
    waiting in the FrameQueue would keep two chunks of them alive; the taxels are 1/100th of that.
    """
    kept, bends = {}, {}
    for h in tally.hands if keep.size else ():
        kept[h] = values[h][keep]
        tally.add_contact(h, kept[h][:, tally.layouts[h].live_mask])
        if keep_bend[h]:
            bends[h] = rasters[h].bend_vector(kept[h])
    frames = {h: rasters[h].frames(v, map_dtype) for h, v in kept.items()} if map_dtype is not None else {}
    return bends, frames


def _frame_maps(frames: dict, n: int, clock: StageClock) -> dict:
    """The (224,224) maps of kept frame n of the chunk, one per hand (`frames`: Rasteriser.frames per hand)."""
    with clock.stage("rasterise"):
        return {h: f[n] for h, f in frames.items()}


def _frame_meta(ref, sync, k: int, rgb_index: int, frame_index: int, hands: list[str]) -> dict:
    """The sample's JSON member for synchronised frame `k` (raw_* fields are added by Frame.finish_raw)."""
    key = sample_key(ref.episode_id, frame_index)
    return {"key": key, "episode_id": ref.episode_id, "frame_index": frame_index,
            "source_frame": rgb_index, "t_rgb_ns": int(sync.t_rgb_ns[k]),
            "t_tactile_ns": {h: int(sync.t_tactile_ns[h][k]) for h in hands},
            "sync_offset_ns": {h: int(sync.skew_ns[h][k]) for h in hands},
            "hands": {h: h in hands for h in HANDS}}


def episode_frames(ref, cfg: PipelineConfig, adapter, tally: EpisodeTally, clock: StageClock | None = None,
                   with_rgb: bool = True, with_maps: bool = True, map_dtype=np.float32) -> Iterator[Frame]:
    """Yield the frames of one planned episode in time order (see the module docstring); raise EpisodeError.

    `ref` must come from planning (layouts resolved). `with_maps=False` renders no map (Frame.maps is
    empty: a dataset whose readers render them from the raw rows, [tactile] maps = "raw"; contact and
    bend vectors are still computed); `map_dtype`: float32 or float16 (a "half" dataset's stored pixels,
    bit for bit: its ingest converts nothing). `with_rgb=False` skips the RGB decode (Frame.rgb is None,
    no RGB-only frames): the benchmarks that only need maps. Per chunk: the tactile rows (paired and unpaired)
    are read, normalised and rasterised first, then the chunk's RGB frames
    are fetched in order; `FrameQueue` releases each paired frame once no
    later dropped frame can add raw rows to it. An episode without a single
    paired frame fails (its RGB-only frames were only spooled).
    """
    clock = clock or StageClock()
    hands = [h for h in HANDS if h in ref.hands]
    tally.start(ref, hands, planned_layouts(ref, hands), cfg.out_of_range)
    layouts = tally.layouts
    with clock.stage("decode"):
        opened = adapter.open(ref, cfg.adapter.params)
    with opened as streams:
        sync = tally.sync = _pair_clocks(ref, cfg, streams, hands, adapter)
        tally.dropped = list(sync.dropped)
        normalisers = tally.normalisers = {h: Normaliser(cfg.normalise_for(layouts[h]), layouts[h]) for h in hands}
        with clock.stage("normalise"):
            _fit_episode_baselines(ref, cfg, adapter, streams, sync, normalisers)
        rasters = {h: rasteriser_for(layouts[h], cfg.tactile.raster_mode) for h in hands}
        keep_bend = {h: cfg.tactile.keep_bend and len(layouts[h].bend_cells) > 0 for h in hands}
        fetcher, unpaired = rgb_source(ref, cfg, streams, sync, clock, with_rgb)
        plans = ({h: RowPlan.build(streams.tactile_timestamps_ns[h], sync.tactile_index[h], sync.t_rgb_ns)
                  for h in hands} if cfg.tactile.keep_raw else {})
        tally.count_row_plans(plans)
        grids = {h: tuple(layouts[h].grid) for h in hands}
        queue = FrameQueue(lambda f: f.finish_raw(grids))
        emit = RgbOnlyFrames(ref, tally, fetcher, unpaired)
        total = int(sync.rgb_index.size)
        chunk = cfg.tactile.chunk_frames
        for start in range(0, total, chunk):
            stop = min(total, start + chunk)
            rgb_idx = sync.rgb_index[start:stop]
            with frame_errors(ref, int(rgb_idx[0])):
                values, ok, raws = read_chunk(ref, streams, tally, normalisers, start, stop, clock, plans)
                if fetcher is not None and not cfg.rgb.keep_unpaired:
                    for j in np.flatnonzero(~ok):
                        fetcher.discard(rgb_idx[j])
                with clock.stage("rasterise"):
                    bends, frames = _kept_values(values, np.flatnonzero(ok), rasters, keep_bend, tally,
                                                 map_dtype if with_maps else None)
            n = 0
            for j in range(stop - start):
                k, i = start + j, int(rgb_idx[j])
                for frame in emit.before((int(sync.t_rgb_ns[k]), i)):
                    yield from queue.push(frame, paired=False)
                rows = frame_raw_rows(sync, raws, start, j)
                if not ok[j]:   # its rows are unpaired now: stored by the previous paired frame (or the next)
                    queue.unpaired_rows(rows)
                    if cfg.rgb.keep_unpaired and fetcher is not None:
                        reason = next(r for x, r in reversed(tally.dropped) if x == i)
                        yield from queue.push(emit.frame(int(sync.t_rgb_ns[k]), i, reason), paired=False)
                    continue
                with frame_errors(ref, i):
                    rgb = fetcher.get(i) if fetcher is not None else None  # timed inside as decode + resize
                meta = _frame_meta(ref, sync, k, i, tally.frames, hands)
                if not streams.has_video:
                    meta["tactile_only"] = True
                tally.frames += 1
                tally.paired += 1
                yield from queue.push(Frame(key=meta["key"], source_frame=i, meta=meta, rgb=rgb,
                                            maps=_frame_maps(frames, n, clock),
                                            bends={h: b[n] for h, b in bends.items()}, raw=rows), paired=True)
                n += 1
        for frame in emit.before(None):
            yield from queue.push(frame, paired=False)
        yield from queue.close()
        if tally.paired == 0:
            why = ("non-finite or out-of-range (out_of_range = \"drop_frame\")"
                   if any(r.startswith("out_of_range:") for _, r in tally.dropped) else "non-finite")
            raise EpisodeError(ref, None, f"no frame left: all {total} synchronised frames had {why} "
                               f"tactile values")
        tally.finish(streams)


class EpisodeStream:
    """One episode as a stream of `Frame`s (iterate once) and its `EpisodeTally`, complete after.

        stream = EpisodeStream(ref, cfg, adapter, clock)
        for frame in stream:
            ...
        record = stream.finished_tally().record()
    """

    def __init__(self, ref, cfg: PipelineConfig, adapter, clock: StageClock | None = None, with_rgb: bool = True,
                 with_maps: bool = True, map_dtype=np.float32):
        self.ref, self.cfg, self.adapter, self.clock, self.with_rgb = ref, cfg, adapter, clock, with_rgb
        self.with_maps, self.map_dtype = with_maps, map_dtype
        self._tally = EpisodeTally()
        self._state = "new"        # -> "reading" -> "done"

    def __iter__(self) -> Iterator[Frame]:
        if self._state != "new":
            raise RuntimeError(f"episode {self.ref.episode_id}: an EpisodeStream is read once")
        self._state = "reading"
        yield from episode_frames(self.ref, self.cfg, self.adapter, self._tally, self.clock, self.with_rgb,
                                  self.with_maps, self.map_dtype)
        self._state = "done"

    def finished_tally(self) -> EpisodeTally:
        """What reading the frames found; only once every frame was read (a partial tally would mislead)."""
        if self._state != "done":
            raise RuntimeError(f"episode {self.ref.episode_id}: the tally is complete only once every frame "
                               f"was read (stream {self._state})")
        return self._tally

