"""Real frames for the benchmarks: episodes of the sample corpus read through the adapters.

`episode_maps` consumes the ingest's own episode generator
(`htdata.ingest.episode.EpisodeStream`: sync -> normalise -> non-finite drop
-> rasterise) without RGB, encoding or writing, so codec numbers are
measured on the maps a dataset really stores and cannot drift from what
ingest does; `bare_bound` times only the unavoidable work of an ingest
(source decode, resize, JPEG + EXR encode) on the same frames with the
same settings, each stage defined as in the ingest's stage timing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.format.codec import encode_rgb
from htdata.format.tactilecodec import encode_tactile
from htdata.ingest import Source
from htdata.ingest.episode import EpisodeStream
from htdata.ingest.pipeline import PipelineConfig, load_pipeline
from htdata.ingest.plan import resolve_layouts, resolve_sources
from htdata.source.adapters import get_adapter
from htdata.source.rgb import to_square_224


@dataclass
class EpisodeMaps:
    episode_id: str
    layouts: dict[str, str]                 # hand -> layout id
    rgb_index: np.ndarray                   # (K,) source RGB frame of each kept sample
    maps: dict[str, np.ndarray] = field(default_factory=dict)   # hand -> (K,224,224) float32
    # hand -> tactile row of every synchronised frame (before the non-finite drop): what the ingest reads
    tactile_index: dict[str, np.ndarray] = field(default_factory=dict)


def discover(pipeline: str, root: Path, settings: tuple[str, ...] = ()) -> tuple[PipelineConfig, object, list]:
    """The pipeline (with `--set` overrides), its adapter and its episodes, planned as ingest plans them."""
    cfg = load_pipeline(pipeline)
    if settings:
        cfg = cfg.with_overrides(list(settings))
    adapter = get_adapter(cfg.adapter.name)
    refs = [resolve_layouts(r, cfg) for r in adapter.discover(Path(root), cfg.adapter.params)]
    cfg = resolve_sources([Source(pipeline=cfg, root=Path(root))], [refs])[0].pipeline   # the codec an ingest picks
    return cfg, adapter, refs


def episode_maps(cfg: PipelineConfig, adapter, ref) -> EpisodeMaps:
    """Synchronised, normalised, rasterised maps of one planned episode (frames with NaN taxels dropped)."""
    stream = EpisodeStream(ref, cfg, adapter, with_rgb=False)
    frames = list(stream)
    tally = stream.finished_tally()
    hands = tally.hands
    return EpisodeMaps(ref.episode_id, {h: tally.layouts[h].layout_id for h in hands},
                       np.array([f.source_frame for f in frames], dtype=np.int64),
                       maps={h: np.stack([f.maps[h] for f in frames]) for h in hands},
                       tactile_index={h: tally.sync.tactile_index[h].copy() for h in hands})


def source_rgb_frames(adapter, cfg: PipelineConfig, ref, count: int) -> list[np.ndarray]:
    """The first `count` RGB frames of an episode at camera resolution (RGB order)."""
    frames = []
    with adapter.open(ref, cfg.adapter.params) as streams:
        for _, frame in streams.iter_rgb():
            frames.append(np.ascontiguousarray(frame))
            if len(frames) >= count:
                break
    return frames


def _read_tactile_chunks(streams, em: EpisodeMaps, chunk: int) -> None:
    """The tactile reads of an ingest: every synchronised row, per hand, in chunks of increasing rows."""
    for h, rows in em.tactile_index.items():
        for start in range(0, rows.size, chunk):
            streams.read_tactile(h, np.unique(rows[start:start + chunk]))


def bare_bound(cfg: PipelineConfig, adapter, refs: list) -> dict:
    """Seconds of the unavoidable work of an ingest of `refs`, stage by stage, on the frames it keeps.

    decode_s: opening the episode's streams (timestamps, headers) + decoding
    RGB up to the last kept frame (a stream has to be decoded in order, so
    unwanted frames before it count) + reading the synchronised tactile rows
    in `chunk_frames` chunks: the ingest's "decode" stage. resize_s:
    `rgb.to_square_224` with the pipeline's size, crop and interpolation.
    jpeg_s: `encode_rgb` at the pipeline's quality. exr_s: `encode_tactile`
    of every hand's map with the pipeline's compression and resolved pixel type, when the ingest stores
    maps (`[tactile] maps`; 0 when the readers render them from raw rows). Nothing else (sync,
    normalise, rasterise, JSON, spool, shard writing) is timed; the maps are
    rasterised beforehand, untimed. `open_s`, `rgb_decode_s` and
    `tactile_read_s` split decode_s.
    """
    t = {"open_s": 0.0, "rgb_decode_s": 0.0, "tactile_read_s": 0.0, "resize_s": 0.0, "jpeg_s": 0.0, "exr_s": 0.0}
    frames = 0
    rgb = cfg.rgb
    pixel_type = cfg.codec_settings().tactile_pixel_type
    # maps encoded only where the ingest stores them (a new dataset: "auto" resolved as the ingest does)
    stores_maps = cfg.tactile.maps.resolved(None).stores_maps
    t["maps_stored"] = stores_maps
    for ref in refs:
        em = episode_maps(cfg, adapter, ref)
        wanted = {int(i): k for k, i in enumerate(em.rgb_index)}
        last = max(wanted) if wanted else -1
        t0 = time.perf_counter()
        streams = adapter.open(ref, cfg.adapter.params)
        t["open_s"] += time.perf_counter() - t0
        with streams:
            t0 = time.perf_counter()
            _read_tactile_chunks(streams, em, cfg.tactile.chunk_frames)
            t["tactile_read_s"] += time.perf_counter() - t0
            it = streams.iter_rgb()
            while last >= 0:
                t0 = time.perf_counter()
                item = next(it, None)
                t1 = time.perf_counter()
                t["rgb_decode_s"] += t1 - t0
                if item is None:
                    break
                i, frame = item
                k = wanted.get(int(i))
                if k is not None:
                    square = to_square_224(frame, rgb.size, rgb.crop, rgb.interpolation)
                    t2 = time.perf_counter()
                    encode_rgb(square, rgb.quality)
                    t3 = time.perf_counter()
                    for maps in em.maps.values() if stores_maps else ():
                        encode_tactile(maps[k], cfg.tactile.compression, pixel_type=pixel_type)
                    t4 = time.perf_counter()
                    t["resize_s"] += t2 - t1
                    t["jpeg_s"] += t3 - t2
                    t["exr_s"] += t4 - t3
                    frames += 1
                if int(i) >= last:
                    break
    decode = t["open_s"] + t["rgb_decode_s"] + t["tactile_read_s"]
    total = decode + t["resize_s"] + t["jpeg_s"] + t["exr_s"]
    return {"frames": frames, "decode_s": decode, **t, "total_s": total,
            "frames_per_s": frames / total if total > 0 else 0.0}
