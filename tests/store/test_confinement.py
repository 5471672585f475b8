"""A dataset from a stranger cannot reach outside its folder (issue 26 item 4).

Fails on the code before issue 26: a version whose episodes_file was
`../payload/e.jsonl` (with a matching sha256) validated OK, publish wrote
`site/payload/e.jsonl` outside the destination, readers read a symlinked shard
outside the root, and gc deleted any `*.tar` under shards/, through a symlink.
"""

import hashlib
import json
import os
import subprocess
import sys
import time

import pytest

from htdata.read.reader import DatasetReader
from htdata.store.confine import PathOutsideDataset
from htdata.store.manifest import load_manifest
from tests.factories import rewrite_manifest, write_synthetic_dataset
from tests.factories.legacy import as_format3

EPISODES = [{"episode_id": f"ep_{i}", "task": "pour", "scene": "lab", "hands": ("right",), "num_frames": 3}
            for i in range(2)]


def htdata(*args):
    return subprocess.run([sys.executable, "-m", "htdata.cli", *map(str, args)], capture_output=True, text=True)


def escaping_dataset(tmp_path):
    """A format 3 dataset whose version names `../payload/e.jsonl` (a real file, sha256 matching); the
    format 4 cases (a segment file, a shard a segment names) are in tests/store/test_segments.py."""
    root = as_format3(write_synthetic_dataset(tmp_path / "ds", EPISODES))
    manifest = load_manifest(root)
    payload = tmp_path / "payload"
    payload.mkdir()
    data = (root / manifest["episodes_file"]).read_bytes()
    (payload / "e.jsonl").write_bytes(data)
    manifest["episodes_file"] = "../payload/e.jsonl"
    manifest["episodes_sha256"] = hashlib.sha256(data).hexdigest()
    rewrite_manifest(root, manifest)
    return root


@pytest.mark.parametrize("rel", ["../payload/e.jsonl", "/etc/passwd", "versions/../../x.jsonl", ".."])
def test_schema_refuses_paths_that_leave_the_root(tmp_path, rel):
    from htdata.resources import validate_json

    manifest = load_manifest(write_synthetic_dataset(tmp_path / "ds", EPISODES))
    manifest["episodes_file"] = rel
    with pytest.raises(ValueError):
        validate_json(manifest, "manifest", where="m")
    manifest["episodes_file"] = "versions/v000001/episodes.jsonl"
    validate_json(manifest, "manifest", where="m")


def test_open_and_validate_refuse_dotdot(tmp_path):
    root = escaping_dataset(tmp_path)
    with pytest.raises(PathOutsideDataset, match=r"episodes_file '\.\./payload/e\.jsonl'"):
        DatasetReader(root, validate_manifest=False)
    res = htdata("validate", root)
    assert res.returncode != 0 and "'../payload/e.jsonl'" in res.stdout + res.stderr
    res = htdata("gc", root)
    assert res.returncode != 0 and "'../payload/e.jsonl'" in res.stderr
    assert (tmp_path / "payload" / "e.jsonl").exists()


def test_publish_writes_nothing_outside_the_destination(tmp_path):
    root = escaping_dataset(tmp_path)
    site = tmp_path / "site"
    res = htdata("publish", root, f"file://{site}/ds")
    assert res.returncode != 0 and "../payload/e.jsonl" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert not (site / "payload").exists()


def test_symlinked_shard_outside_the_root_is_refused(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    with DatasetReader(root) as reader:
        name = reader.manifest["shards"][0]["name"]
    shard = root / "shards" / name
    elsewhere = tmp_path / "elsewhere.tar"
    shard.rename(elsewhere)
    shard.symlink_to(elsewhere)
    with DatasetReader(root) as reader, pytest.raises(PathOutsideDataset, match="outside the dataset folder"):
        reader.sample(0)
    res = htdata("validate", root)
    assert res.returncode != 0 and "outside the dataset folder" in res.stdout + res.stderr
    # a symlink that stays inside the root is fine
    inner = root / "shards" / "keep" / name
    inner.parent.mkdir()
    shard.unlink()
    elsewhere.rename(inner)
    shard.symlink_to(inner)
    with DatasetReader(root) as reader:
        assert reader.sample(0)


def test_gc_deletes_only_shard_names_never_through_a_symlink(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    old = time.time() - 30 * 86400
    backup = tmp_path / "home" / "home-backup.tar"
    backup.parent.mkdir()
    backup.write_bytes(b"x" * 4096)
    stray = root / "shards" / "home-backup.tar"          # not a shard name: never gc's to delete
    stray.write_bytes(b"y" * 4096)
    linked = root / "shards" / "shard-000099-000.tar"    # a shard name, but a symlink out of the root
    linked.symlink_to(backup)
    orphan = root / "shards" / "shard-000098-000.tar"    # a real orphan shard: collected
    orphan.write_bytes(b"z" * 4096)
    for p in (backup, stray, orphan):
        os.utime(p, (old, old))
    res = htdata("gc", root)
    assert res.returncode == 0, res.stderr
    assert backup.exists() and stray.exists() and linked.is_symlink() and not orphan.exists()
    # shards/ itself a symlink into a folder holding tars: nothing deleted through it
    folder = tmp_path / "backups"
    folder.mkdir()
    (folder / "shard-000097-000.tar").write_bytes(b"w" * 4096)
    os.utime(folder / "shard-000097-000.tar", (old, old))
    for p in (root / "shards").iterdir():
        p.rename(folder / p.name) if not p.is_symlink() else p.unlink()
    (root / "shards").rmdir()
    (root / "shards").symlink_to(folder)
    res = htdata("gc", root)            # a writer refuses a dataset whose shards/ is a symlink (issue 35 item 6)
    assert res.returncode == 2 and f"{root / 'shards'} is a symlink (to {folder})" in res.stderr, res.stderr
    assert (folder / "shard-000097-000.tar").exists()


def test_manifest_shard_name_with_a_slash_is_refused(tmp_path):
    root = as_format3(write_synthetic_dataset(tmp_path / "ds", EPISODES))
    manifest = json.loads((root / "dataset.json").read_text())
    manifest["shards"][0]["name"] = "../../x.tar"
    rewrite_manifest(root, manifest)
    with pytest.raises(PathOutsideDataset, match=r"shards\[0\]\.name"):
        DatasetReader(root, validate_manifest=False)
