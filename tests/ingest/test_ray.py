"""`--executor ray` writes the same dataset as the local process pool, byte for byte.

A local Ray (2 CPUs, no dashboard, bound to loopback, no usage stats) is
started once by the test; the ingest's RayExecutor joins it. Ray is a
declared dependency (`[ray]` extra, installed by `make setup`): a missing
`ray` fails the test instead of skipping it.
"""

from __future__ import annotations

import json
import os
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
from tests.factories import COLOURS, PERIOD, ingest_cli, small_pipeline, temp_leftovers


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


def files_outside(paths: list[Path]) -> set[str]:
    """Every file under the given folders (to spot files Ray leaves behind)."""
    return {str(p) for folder in paths if folder.exists() for p in folder.rglob("*")}


def test_ray_executor_equals_process_pool(tmp_path, monkeypatch):
    import ray  # a declared dependency: ImportError fails the test

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    ot, ta = make_mixed_sources(tmp_path / "raw")
    pipes = ["--pipeline", f"{small_pipeline(tmp_path, 'opentouch', 8)}={ot}",
             "--pipeline", f"{small_pipeline(tmp_path, 'touchanything', 8)}={ta}"]

    pool_out = tmp_path / "pool"
    assert ingest_cli(*pipes, pool_out, workers=2) == 0

    work = tmp_path / "cwd"      # an empty working directory: anything Ray drops there shows
    work.mkdir()
    monkeypatch.chdir(work)
    watched = [work, tmp_path / "raw"]
    before = files_outside(watched)
    ray_out = tmp_path / "ray"
    assert not ray.is_initialized()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _node_ip_address="127.0.0.1",
             object_store_memory=100 * 1024 * 1024)
    try:
        assert ingest_cli("--executor", "ray", *pipes, ray_out, workers=2) == 0
        report = json.loads((ray_out / "reports" / "ingest.json").read_text())
        assert report["units_run"] == report["units"] >= 4 and report["failures"] == []
        # a second run on the same cluster and directory resumes every unit
        assert ingest_cli("--executor", "ray", *pipes, ray_out, workers=2) == 0
        again = json.loads((ray_out / "reports" / "ingest.json").read_text())
        assert again["units_resumed"] == again["units"] and again["timing"]["frames"] == 0
    finally:
        ray.shutdown()
    assert not ray.is_initialized()

    ray_samples, ray_shards = dataset_contents(ray_out)
    pool_samples, pool_shards = dataset_contents(pool_out)
    assert len(pool_samples) == 9 + 5 + 7 + 11 + 6
    assert list(ray_samples) == list(pool_samples)          # same keys in the same (index) order
    for key, members in pool_samples.items():
        assert ray_samples[key] == members, key             # same member bytes
    assert ray_shards == pool_shards                        # same shard names and sha256
    ray_manifest, pool_manifest = (json.loads((out / MANIFEST_FILE).read_text()) for out in (ray_out, pool_out))
    for listed in ("index_file", "episodes_file"):          # the current version's index.npy / episodes.jsonl
        assert (ray_out / ray_manifest[listed]).read_bytes() == (pool_out / pool_manifest[listed]).read_bytes()
    # Ray left nothing in the dataset, the sources or the working directory
    assert temp_leftovers(ray_out) == []
    assert sorted(p.name for p in ray_out.iterdir()) == sorted(p.name for p in pool_out.iterdir())
    assert files_outside(watched) == before and before == files_outside([tmp_path / "raw"])
    assert "RAY_ADDRESS" not in os.environ
