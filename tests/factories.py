"""Build small, valid, committed datasets from in-memory frames (for tests).

    from tests.factories import write_synthetic_dataset
    root = write_synthetic_dataset(tmp_path / "ds", episodes=[
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": ("right",), "num_frames": 5},
        {"episode_id": "ep_b", "task": "wipe", "scene": "office", "hands": ("left", "right"), "num_frames": 3,
         "layouts": {"left": "glove_l", "right": "glove_r"}},
    ])

Frames are seeded per (seed, episode_id, frame), so `synthetic_members`
regenerates exactly the bytes that were written (tests compare against it).
Everything goes through the real writer APIs (codec, ShardWriter,
commit_dataset). Layout ids default to "test_full" with full-canvas
coverage; pass `coverages={layout_id: (224,224) uint8}` for real ones (e.g.
from htdata.layouts + Rasteriser) and `canonical=CanonicalArtifact(...)`.
"""

from __future__ import annotations

import io
import json
import zlib
from pathlib import Path

import cv2
import numpy as np

from htdata.codec import DEFAULT_CODEC_INFO, encode_rgb, encode_tactile
from htdata.manifest import CanonicalArtifact, LayoutArtifact, UnitResult, commit_dataset
from htdata.shardio import ShardWriter, sample_key

DEFAULT_LAYOUT = "test_full"
CANVAS = 224
FRAME_NS = 33_333_333


def default_canonical() -> CanonicalArtifact:
    """A small stand-in template: six part bands over a hand-shaped box."""
    part_map = np.zeros((CANVAS, CANVAS), np.uint8)
    # fingers: five columns in the top half (little .. thumb, thumb on the right), palm below
    for part, x0 in zip((5, 4, 3, 2, 1), (20, 60, 100, 140, 180)):
        part_map[10:110, x0:x0 + 30] = part
    part_map[110:214, 20:210] = 6
    region_map = part_map.copy()
    region_map[60:110][part_map[60:110] > 0] += 10  # distal vs proximal places
    doc = {"canvas": CANVAS, "synthetic": True,
           "parts": {"1": "thumb", "2": "index", "3": "middle", "4": "ring", "5": "little", "6": "palm"}}
    return CanonicalArtifact(document=doc, region_map=region_map, part_map=part_map)


def _rng(seed: int, episode_id: str, frame: int, salt: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(episode_id.encode()), frame, salt])


def synthetic_rgb(seed: int, episode_id: str, frame: int) -> np.ndarray:
    """Smooth random colours (JPEG-friendly) + a little noise, (224,224,3) uint8."""
    rng = _rng(seed, episode_id, frame, 0)
    small = rng.integers(0, 256, size=(8, 8, 3), dtype=np.uint8)
    big = cv2.resize(small, (CANVAS, CANVAS), interpolation=cv2.INTER_LINEAR).astype(np.int16)
    big += rng.integers(-6, 7, size=big.shape, dtype=np.int16)
    return np.clip(big, 0, 255).astype(np.uint8)


def synthetic_tactile(seed: int, episode_id: str, frame: int, hand: str, coverage: np.ndarray) -> np.ndarray:
    """Sparse contact: a few Gaussian blobs inside the coverage, peak exactly 1.0 on even frames."""
    rng = _rng(seed, episode_id, frame, 1 if hand == "left" else 2)
    yy, xx = np.mgrid[0:CANVAS, 0:CANVAS].astype(np.float32)
    m = np.zeros((CANVAS, CANVAS), np.float32)
    for _ in range(int(rng.integers(1, 4))):
        cy, cx = rng.uniform(20, 204, size=2)
        sigma = rng.uniform(4, 14)
        m += rng.uniform(0.2, 0.9) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * sigma ** 2))
    m[m < 0.02] = 0.0  # exact zeros away from contact, like real maps
    m = np.clip(m, 0.0, 1.0) * (coverage > 0)
    if frame % 2 == 0 and m.max() > 0:
        m[np.unravel_index(np.argmax(m), m.shape)] = 1.0
    return m.astype(np.float32)


def synthetic_members(spec: dict, frame: int, seed: int, coverages: dict[str, np.ndarray],
                      bend_dims: int = 0) -> dict[str, bytes]:
    """The tar members of one synthetic sample (deterministic)."""
    eid = spec["episode_id"]
    hands = tuple(spec["hands"])
    key = sample_key(eid, frame)
    t_rgb = 1_000_000_000 + frame * FRAME_NS
    meta = {
        "key": key, "episode_id": eid, "frame_index": frame, "t_rgb_ns": t_rgb,
        "t_tactile_ns": {h: t_rgb + 1_000 * (i + 1) for i, h in enumerate(hands)},
        "sync_offset_ns": {h: 1_000 * (i + 1) for i, h in enumerate(hands)},
        "hands": {"left": "left" in hands, "right": "right" in hands},
    }
    members = {"json": json.dumps(meta, sort_keys=True).encode(),
               "rgb.jpg": encode_rgb(synthetic_rgb(seed, eid, frame), quality=95)}
    layouts = episode_layouts(spec)
    for hand in ("left", "right"):
        if hand in hands:
            m = synthetic_tactile(seed, eid, frame, hand, coverages[layouts[hand]])
            members[f"tactile_{hand}.exr"] = encode_tactile(m, where=f"{key}.tactile_{hand}")
    if bend_dims:
        for hand in ("left", "right"):
            if hand in hands:
                buf = io.BytesIO()
                np.save(buf, _rng(seed, eid, frame, 3).random(bend_dims, dtype=np.float32))
                members[f"bend_{hand}.npy"] = buf.getvalue()
    return members


def episode_layouts(spec: dict) -> dict[str, str]:
    given = dict(spec.get("layouts") or {})
    return {h: given.get(h, DEFAULT_LAYOUT) for h in spec["hands"]}


def write_synthetic_dataset(root, episodes: list[dict], seed: int = 0,
                            coverages: dict[str, np.ndarray] | None = None,
                            canonical: CanonicalArtifact | None = None,
                            samples_per_shard: int = 4, episodes_per_unit: int = 2,
                            bend_dims: int = 0, fps: float = 30.0) -> Path:
    """Write and commit a dataset at `root`; returns root as a Path.

    episodes: [{"episode_id", "task", "scene", "hands": ("right",) | ("left","right"),
    "num_frames", optional "layouts": {hand: layout_id}, optional "source_split"}].
    Episodes are grouped `episodes_per_unit` per work unit; small
    `samples_per_shard` makes episodes span shards.
    """
    root = Path(root)
    coverages = dict(coverages or {})
    for spec in episodes:
        if spec["num_frames"] < 1:
            raise ValueError(f"episode {spec['episode_id']}: num_frames must be >= 1")
        for hand, layout_id in episode_layouts(spec).items():
            coverages.setdefault(layout_id, np.ones((CANVAS, CANVAS), np.uint8))
    layout_hands = {}
    for spec in episodes:
        for hand, layout_id in episode_layouts(spec).items():
            layout_hands.setdefault(layout_id, hand)

    units = []
    for u, start in enumerate(range(0, len(episodes), episodes_per_unit)):
        group = episodes[start:start + episodes_per_unit]
        with ShardWriter(root / "shards", unit=u, samples_per_shard=samples_per_shard) as writer:
            for spec in group:
                for frame in range(spec["num_frames"]):
                    writer.add_sample(sample_key(spec["episode_id"], frame),
                                      synthetic_members(spec, frame, seed, coverages, bend_dims))
        records = []
        for spec in group:
            rec = {
                "episode_id": spec["episode_id"], "source": "synthetic",
                "source_ref": f"memory::{spec['episode_id']}", "task": spec["task"], "scene": spec["scene"],
                "hands": list(spec["hands"]), "layouts": episode_layouts(spec),
                "num_frames": spec["num_frames"], "fps": fps, "stats": {}, "sync": {},
                "dropped_frames": 0, "notes": [],
            }
            if "source_split" in spec:
                rec["source_split"] = spec["source_split"]
            records.append(rec)
        units.append(UnitResult(unit=u, shards=writer.shards, samples=writer.samples, episodes=records))

    layouts = [LayoutArtifact(layout_id=lid, document={"layout_id": lid, "hand": layout_hands.get(lid, "right"),
                                                       "synthetic": True},
                              coverage=np.asarray(cov, np.uint8))
               for lid, cov in coverages.items()]
    commit_dataset(root, units, layouts=layouts, canonical=canonical or default_canonical(),
                   codec=DEFAULT_CODEC_INFO, sources=[{"name": "synthetic", "seed": seed}],
                   created="2000-01-01T00:00:00+00:00")
    return root


# Three episodes covering one hand, two hands and a single frame; used by the reader and torch tests.
MIXED_HANDS_EPISODES = [
    {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": ("right",), "num_frames": 5,
     "layouts": {"right": "glove_r"}},
    {"episode_id": "ep_b", "task": "wipe", "scene": "office", "hands": ("left", "right"), "num_frames": 4,
     "layouts": {"left": "glove_l", "right": "glove_r"}},
    {"episode_id": "ep_c", "task": "pour", "scene": "office", "hands": ("left",), "num_frames": 1,
     "layouts": {"left": "glove_l"}},
]
