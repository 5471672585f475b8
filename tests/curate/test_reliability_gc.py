"""gc never breaks a running reader inside the retention window, and says so when it did (--force).

Fails on the code before issue 18: gc deleted a superseded version's files at
once (an open reader's later reads hit a bare FileNotFoundError), had no
--retention, and an interrupted gc left versions/vN/ that no later gc removed.
"""

import os
import subprocess
import sys
import time

import pytest

from htdata.errors import HtdataError
from htdata.read.reader import DatasetReader
from htdata.store.versions import list_versions
from tests.factories import write_synthetic_dataset

EPISODES = [{"episode_id": f"ep_{i}", "task": "pour" if i % 2 else "wipe", "scene": "lab", "hands": ("right",),
             "num_frames": 3 + i} for i in range(5)]
DAY = 86400


def htdata(*args):
    return subprocess.run([sys.executable, "-m", "htdata.cli", *map(str, args)], capture_output=True, text=True)


def two_versions(root):
    root = write_synthetic_dataset(root, EPISODES)
    assert htdata("rm", root, "ep_0").returncode == 0      # v2 re-packs unit 0: v1's shards 0-* are v1-only
    return root


def age(path, days):
    t = time.time() - days * DAY
    os.utime(path, (t, t))


def test_gc_help_states_the_retention_rule():
    out = htdata("gc", "--help").stdout
    assert "--retention" in out and "default 7d" in out and "--force" in out


def test_open_reader_keeps_reading_inside_the_retention_window(tmp_path):
    root = two_versions(tmp_path / "ds")
    reader = DatasetReader(root, version=1)                  # a training job on version 1, no shard opened yet
    res = htdata("gc", root, "--keep-versions", "1")          # default window: 7 days
    assert res.returncode == 0, res.stderr
    assert len([reader.sample(i) for i in range(len(reader))]) == 25   # before #18: FileNotFoundError
    assert "keep version 1: superseded less than 7d ago" in res.stdout
    assert list_versions(root) == [1, 2]
    dry = htdata("gc", root, "--dry-run")
    assert "keep version 1" in dry.stdout and "collectable after" in dry.stdout


def test_gc_collects_once_the_window_has_passed(tmp_path):
    root = two_versions(tmp_path / "ds")
    age(root / "versions" / "v000002.json", 8)                 # v1 superseded 8 days ago
    dry = htdata("gc", root, "--dry-run")
    assert "would delete version 1" in dry.stdout and list_versions(root) == [1, 2]
    res = htdata("gc", root)
    assert res.returncode == 0 and "delete version 1" in res.stdout
    assert list_versions(root) == [2] and len(DatasetReader(root)) == 22


def test_retention_zero_needs_force_and_then_readers_get_one_named_error(tmp_path):
    root = two_versions(tmp_path / "ds")
    reader = DatasetReader(root, version=1)
    refused = htdata("gc", root, "--retention", "0")
    assert refused.returncode == 2 and "--force" in refused.stderr and "reader" in refused.stderr
    assert list_versions(root) == [1, 2]
    res = htdata("gc", root, "--retention", "0", "--force")
    assert res.returncode == 0 and list_versions(root) == [2]
    with pytest.raises(HtdataError, match=r"version 1 was removed by `htdata gc --keep-versions 1 --retention 0`"):
        for i in range(len(reader)):
            reader.sample(i)
    with pytest.raises(HtdataError, match="version 1 was removed by"):
        DatasetReader(root, version=1)


def test_interrupted_gc_leftover_folder_is_removed_by_the_next_gc(tmp_path):
    root = two_versions(tmp_path / "ds")
    (root / "versions" / "v000001.json").unlink()             # what a gc killed between vN.json and vN/ leaves
    assert (root / "versions" / "v000001").is_dir()
    res = htdata("gc", root)
    assert res.returncode == 0, res.stderr
    assert not (root / "versions" / "v000001").exists()
    assert len(DatasetReader(root)) == 22
