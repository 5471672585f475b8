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

from htdata.format.table import MANIFEST_FILE
from tests.factories import ingest_cli, small_pipeline, temp_leftovers
from tests.factories.executors import dataset_contents, make_mixed_sources, record_digests


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
    assert record_digests(ray_manifest) == record_digests(pool_manifest)   # the version's records, byte for byte
    # Ray left nothing in the dataset, the sources or the working directory
    assert temp_leftovers(ray_out) == []
    assert sorted(p.name for p in ray_out.iterdir()) == sorted(p.name for p in pool_out.iterdir())
    assert files_outside(watched) == before and before == files_outside([tmp_path / "raw"])
    assert "RAY_ADDRESS" not in os.environ
