"""Sources and comparisons the executor tests share (tests/ingest/test_ray.py, test_ray_cluster.py).

`make_mixed_sources`: two OpenTouch scenes (four clips) and one two-handed TouchAnything episode;
`dataset_contents`: every sample's member bytes by key and the manifest's shard list, to compare two
datasets byte for byte; `same_dataset_bytes`: that, plus the current version's index and episode records.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from htdata.format.table import MANIFEST_FILE
from htdata.synthetic.formats import (
    OpenTouchClip,
    TouchAnythingEpisode,
    write_opentouch_annotations,
    write_opentouch_scene,
    write_touchanything_episode,
)
from tests.factories import COLOURS, PERIOD


def make_mixed_sources(root: Path) -> tuple[Path, Path]:
    """Four OpenTouch clips in two scenes + one two-handed TouchAnything episode."""
    from htdata.glove.layouts import load_layout

    ot = root / "ot"
    rng = np.random.default_rng(7)
    rows = []
    for scene, lengths in (("home_kitchen_p1", (9, 5)), ("office_desk_p2", (7, 11))):
        clips = []
        for n, t in enumerate(lengths):
            demo = f"demo_{n + 1:02d}"
            frames = [np.full((48, 64, 3), COLOURS[(n + k) % 4], np.uint8) for k in range(t)]
            pressure = rng.uniform(1000, 3072, size=(t, 16, 16)).astype(np.float32)
            clips.append(OpenTouchClip(demo, np.arange(t, dtype=np.int64) * PERIOD + 10**12, pressure, frames))
            rows.append({"id": f"{scene}::{demo}", "action": "pour" if n else "wipe"})
        write_opentouch_scene(ot / f"{scene}.hdf5", clips)
    write_opentouch_annotations(ot / "annotations.csv", rows)

    ta = root / "ta"
    t = 6
    grids = {}
    for hand in ("left", "right"):
        lay = load_layout(f"touchanything_{hand}_21x21")
        g = np.full((t, 21, 21), np.nan, np.float32)
        g[:, lay.live_mask] = rng.uniform(0, 1, (t, int(lay.live_mask.sum()))).astype(np.float32)
        grids[hand] = g
    episode = TouchAnythingEpisode(left_grid=grids["left"], right_grid=grids["right"],
                                   chest_frames=[np.full((480, 640, 3), COLOURS[2], np.uint8)] * t,
                                   ts_epoch_s=1.7e9 + np.arange(t) / 30.0)
    write_touchanything_episode(ta / "Home" / "plug_usb" / "20260320_135743_682", episode, wrist_videos=False)
    return ot, ta


def dataset_contents(out: Path) -> tuple[dict, list]:
    """{key: {suffix: bytes}} over every sample, and the manifest's (shard name, sha256) list."""
    from htdata.read.reader import DatasetReader

    reader = DatasetReader(out)
    samples = {}
    for i in range(len(reader)):
        members = reader.sample(i)
        samples[json.loads(members["json"])["key"]] = members
    return samples, [(s["name"], s["sha256"]) for s in reader.manifest["shards"]]


def record_digests(manifest: dict) -> tuple:
    """A version's records by their sha256: its episode records and index as a reader sees them, and its
    segment files (format 4: each file's sha256, which a reader checks on every read)."""
    return (manifest["episodes_sha256"], manifest["index_sha256"],
            [(e["records_sha256"], e["index_sha256"]) for e in manifest.get("segments", [])])


def same_dataset_bytes(a: Path, b: Path) -> None:
    """Assert datasets `a` and `b` hold the same samples (keys in index order, member bytes), shards
    (names, sha256), index and episode records, byte for byte."""
    samples_a, shards_a = dataset_contents(a)
    samples_b, shards_b = dataset_contents(b)
    assert list(samples_a) == list(samples_b)                 # same keys in the same (index) order
    for key, members in samples_a.items():
        assert samples_b[key] == members, key                 # same member bytes
    assert shards_a == shards_b                               # same shard names and sha256
    manifest_a, manifest_b = (json.loads((out / MANIFEST_FILE).read_text()) for out in (a, b))
    assert record_digests(manifest_a) == record_digests(manifest_b)   # the current version's records, byte for byte
