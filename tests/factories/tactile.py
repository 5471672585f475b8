"""Committed datasets from taxel series of REAL glove layouts (for the stats, health and idle tests).

    root = write_taxel_dataset(tmp_path / "ds", [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen",
         "hands": {"right": ("opentouch_right_16x16", grids)}},     # grids (T,H,W) in [0,1]
    ])

Maps are rendered with the real Rasteriser, so sampling them back at taxel
centres returns the grids (up to EXR half precision). `nan_frames={hand:
[frames]}` in an episode spec stores a NaN pixel in those maps (written with
the raw EXR writer: the value rule would refuse it). `clean_series` makes
smooth moving-contact recordings; `plant` puts faults into known taxels.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from htdata.format.codec import DEFAULT_CODEC_INFO, encode_rgb
from htdata.format.shardio import ShardWriter, sample_key
from htdata.format.tactilecodec import encode_exr, encode_tactile
from htdata.glove.layouts import load_canonical, load_layout
from htdata.glove.rasterise import Rasteriser
from htdata.store.manifest import CanonicalArtifact, LayoutArtifact, UnitResult
from tests.factories import commit_dataset

RIGHT = "opentouch_right_16x16"
LEFT = "touchanything_left_21x21"
_RGB = encode_rgb(np.full((224, 224, 3), 90, np.uint8), quality=80)


def clean_series(layout_id: str, frames: int, seed: int = 0, blobs: int = 3, noise: float = 0.0) -> np.ndarray:
    """(T,H,W) smooth contact: Gaussian blobs in raw-grid coordinates drifting slowly, pressing and releasing."""
    layout = load_layout(layout_id)
    H, W = layout.grid
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    t = np.arange(frames, dtype=np.float32)
    out = np.zeros((frames, H, W), np.float32)
    for _ in range(blobs):
        y0, x0 = rng.uniform(0, H), rng.uniform(0, W)
        vy, vx = rng.uniform(-0.05, 0.05, size=2)
        sigma = rng.uniform(1.5, 3.0)
        period = rng.uniform(20, 60)
        amp = np.clip(np.sin(2 * np.pi * t / period + rng.uniform(0, 6.3)), 0, None) * rng.uniform(0.4, 0.9)
        for k in range(frames):
            cy, cx = y0 + vy * k, x0 + vx * k
            out[k] += amp[k] * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * sigma ** 2))
    if noise:
        out += rng.normal(0, noise, size=out.shape).astype(np.float32)
    out[out < 0.01] = 0.0
    return np.clip(out, 0.0, 1.0)


def live_cells(layout_id: str) -> np.ndarray:
    return np.argwhere(load_layout(layout_id).live_mask)


def write_taxel_dataset(root, episodes: list[dict], samples_per_shard: int = 16) -> Path:
    """Write and commit one work unit per episode; returns root."""
    root = Path(root)
    canon = load_canonical()
    layouts: dict[str, LayoutArtifact] = {}
    units = []
    for u, spec in enumerate(episodes):
        hands = spec["hands"]
        n = int(spec.get("num_frames") or len(next(iter(hands.values()))[1]))
        maps = {}
        for hand, (layout_id, grids) in hands.items():
            r = Rasteriser(layout_id)
            maps[hand] = r.render(np.asarray(grids, np.float32))
            if layout_id not in layouts:
                doc = json.loads(Path(r.layout.path).read_text())
                layouts[layout_id] = LayoutArtifact(layout_id=layout_id, document=doc, coverage=r.coverage)
        eid = spec["episode_id"]
        with ShardWriter(root / "shards", unit=u, samples_per_shard=samples_per_shard) as writer:
            for frame in range(n):
                key = sample_key(eid, frame)
                t = 1_000_000_000 + frame * 33_333_333
                meta = {"key": key, "episode_id": eid, "frame_index": frame, "t_rgb_ns": t,
                        "t_tactile_ns": {h: t for h in hands}, "sync_offset_ns": {h: 0 for h in hands},
                        "hands": {h: h in hands for h in ("left", "right")}}
                members = {"json": json.dumps(meta, sort_keys=True).encode(), "rgb.jpg": _RGB}
                for hand in ("left", "right"):
                    if hand in hands:
                        m = maps[hand][frame]
                        if frame in spec.get("nan_frames", {}).get(hand, ()):
                            m = m.copy()
                            m[112, 112] = np.nan
                            members[f"tactile_{hand}.exr"] = encode_exr(m)
                        else:
                            members[f"tactile_{hand}.exr"] = encode_tactile(m, where=key)
                writer.add_sample(key, members)
        rec = {"episode_id": eid, "source": spec.get("source", "synthetic"), "source_ref": f"memory::{eid}",
               "task": spec.get("task", "pour"), "scene": spec.get("scene", "lab"), "hands": sorted(hands),
               "layouts": {h: lid for h, (lid, _) in hands.items()}, "num_frames": n,
               "fps": float(spec.get("fps", 30.0)), "stats": {}, "sync": spec.get("sync", {}),
               "dropped_frames": 0, "notes": []}
        units.append(UnitResult(unit=u, shards=writer.shards, samples=writer.samples, episodes=[rec]))
    commit_dataset(root, units, layouts=list(layouts.values()),
                   canonical=CanonicalArtifact(document=canon.to_dict(), region_map=canon.region_map,
                                               part_map=canon.part_map),
                   codec=DEFAULT_CODEC_INFO, sources=[{"name": "synthetic"}], created="2000-01-01T00:00:00+00:00")
    return root
