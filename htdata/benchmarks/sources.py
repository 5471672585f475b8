"""Real frames for the benchmarks: episodes of the sample corpus read through the adapters.

`episode_maps` reproduces the ingest's tactile path (sync -> normalise ->
rasterise) without encoding or writing, so codec numbers are measured on the
maps a dataset really stores; `bare_bound` times only the unavoidable work of
an ingest (source decode, area resize, JPEG + EXR encode) on the same frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from htdata.codec import encode_rgb, encode_tactile
from htdata.ingest import get_adapter
from htdata.layouts import load_layout
from htdata.normalise import Normaliser
from htdata.pipeline import PipelineConfig, load_pipeline
from htdata.rasterise import Rasteriser
from htdata.rgb import centre_square
from htdata.sync import pair

HANDS = ("left", "right")


@dataclass
class EpisodeMaps:
    episode_id: str
    layouts: dict[str, str]                 # hand -> layout id
    rgb_index: np.ndarray                   # (K,) source RGB frame of each kept sample
    maps: dict[str, np.ndarray] = field(default_factory=dict)   # hand -> (K,224,224) float32


def discover(pipeline: str, root: Path) -> tuple[PipelineConfig, object, list]:
    cfg = load_pipeline(pipeline)
    adapter = get_adapter(cfg.adapter.name)
    return cfg, adapter, adapter.discover(Path(root), cfg.adapter.params)


def episode_maps(cfg: PipelineConfig, adapter, ref, rasters: dict | None = None) -> EpisodeMaps:
    """Synchronised, normalised, rasterised maps of one episode (frames with NaN taxels dropped)."""
    rasters = {} if rasters is None else rasters
    hands = [h for h in HANDS if h in ref.hands]
    layouts = {h: load_layout(cfg.layout_for(h, ref.layouts[h])) for h in hands}
    with adapter.open(ref, cfg.adapter.params) as streams:
        sync = pair(streams.rgb_timestamps_ns, {h: streams.tactile_timestamps_ns[h] for h in hands},
                    cfg.sync.max_skew_ns, cfg.sync.policy)
        values, ok = {}, np.ones(sync.rgb_index.size, dtype=bool)
        for h in hands:
            uniq, inverse = np.unique(sync.tactile_index[h], return_inverse=True)
            raw = np.asarray(streams.read_tactile(h, uniq))[inverse.reshape(-1)]
            norm = Normaliser(cfg.normalise_for(layouts[h]), layouts[h])
            norm.fit_baseline(raw)
            values[h], finite = norm.apply(raw)
            ok &= finite
    out = EpisodeMaps(ref.episode_id, {h: layouts[h].layout_id for h in hands}, sync.rgb_index[ok])
    for h in hands:
        key = (layouts[h].layout_id, cfg.tactile.raster_mode)
        if key not in rasters:
            rasters[key] = Rasteriser(layouts[h], mode=cfg.tactile.raster_mode)
        out.maps[h] = rasters[key].render(values[h][ok])
    return out


def source_rgb_frames(adapter, cfg: PipelineConfig, ref, count: int) -> list[np.ndarray]:
    """The first `count` RGB frames of an episode at camera resolution (RGB order)."""
    frames = []
    with adapter.open(ref, cfg.adapter.params) as streams:
        for _, frame in streams.iter_rgb():
            frames.append(np.ascontiguousarray(frame))
            if len(frames) >= count:
                break
    return frames


def bare_bound(cfg: PipelineConfig, adapter, refs: list) -> dict:
    """Seconds of decode + INTER_AREA resize + JPEG encode + EXR encode over `refs`' kept frames.

    No sync, normalise, spool or shard write is timed: maps are rasterised
    beforehand (untimed). Unwanted source frames are decoded (a stream has to
    be), as in the ingest.
    """
    t = {"decode_s": 0.0, "resize_s": 0.0, "jpeg_s": 0.0, "exr_s": 0.0}
    frames, rasters = 0, {}
    size = cfg.rgb.size
    for ref in refs:
        em = episode_maps(cfg, adapter, ref, rasters)
        wanted = {int(i): k for k, i in enumerate(em.rgb_index)}
        last = max(wanted) if wanted else -1
        with adapter.open(ref, cfg.adapter.params) as streams:
            it = streams.iter_rgb()
            while True:
                t0 = time.perf_counter()
                item = next(it, None)
                t1 = time.perf_counter()
                t["decode_s"] += t1 - t0
                if item is None:
                    break
                i, frame = item
                k = wanted.get(int(i))
                if k is not None:
                    square = cv2.resize(np.ascontiguousarray(centre_square(frame)), (size, size),
                                        interpolation=cv2.INTER_AREA)
                    t2 = time.perf_counter()
                    encode_rgb(square, cfg.rgb.quality)
                    t3 = time.perf_counter()
                    for h, maps in em.maps.items():
                        encode_tactile(maps[k], cfg.tactile.compression)
                    t4 = time.perf_counter()
                    t["resize_s"] += t2 - t1
                    t["jpeg_s"] += t3 - t2
                    t["exr_s"] += t4 - t3
                    frames += 1
                if int(i) >= last:
                    break
    total = sum(t.values())
    return {"frames": frames, **t, "total_s": total,
            "frames_per_s": frames / total if total > 0 else 0.0}
