"""A full disk and a `.lock` that is a directory: one line naming the problem, nothing lost, no temp
lock file left. Before issue 18 both were tracebacks and a full disk left `.lock.<pid>.tmp` behind.

The full disk is simulated by making fsync(2) fail with ENOSPC for the chosen files (what a full
file system reports when the data cannot be written back); the code under test is the real one.
"""

import errno
import os

from htdata.cli import main
from htdata.read.reader import DatasetReader
from htdata.store.versions import list_versions
from tests.factories import write_synthetic_dataset

EPISODES = [{"episode_id": f"ep_{i}", "task": "pour", "scene": "lab", "hands": ("right",), "num_frames": 3}
            for i in range(3)]


def fail_fsync_for(monkeypatch, match):
    real = os.fsync

    def fsync(fd):
        try:
            path = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            path = ""
        if match(path):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)


def test_full_disk_at_the_lock_is_one_line_and_leaves_no_temp_lock(tmp_path, monkeypatch, capsys):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    fail_fsync_for(monkeypatch, lambda p: ".lock." in p)
    assert main(["rm", str(root), "ep_1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err and "nothing was committed" in err
    assert not list(root.glob(".lock*"))
    assert list_versions(root) == [1]


def test_full_disk_while_writing_a_version_is_one_line_and_the_current_version_stays(tmp_path, monkeypatch,
                                                                                       capsys):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    before = [DatasetReader(root).sample(i) for i in range(9)]
    fail_fsync_for(monkeypatch, lambda p: "/versions/" in p)
    assert main(["rm", str(root), "ep_1"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    monkeypatch.undo()
    assert list_versions(root) == [1] and [DatasetReader(root).sample(i) for i in range(9)] == before
    assert not (root / ".lock").exists()
    assert main(["rm", str(root), "ep_1"]) == 0 and list_versions(root) == [1, 2]   # space back: works


def test_lock_that_is_a_directory_is_one_line(tmp_path, capsys):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    (root / ".lock").mkdir()
    assert main(["rm", str(root), "ep_1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ".lock: is a directory" in err
    assert list_versions(root) == [1]
