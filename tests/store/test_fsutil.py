"""Atomic writes: content replaced whole, temp files gone, and files readable like any other file."""

import os
import stat

import pytest

from htdata.store.fsutil import FILE_MODE, atomic_open, write_bytes_atomic


def test_atomic_write_replaces_whole_and_gets_the_usual_mode(tmp_path):
    path = tmp_path / "sub" / "dataset.json"
    write_bytes_atomic(path, b"one")
    write_bytes_atomic(path, b"two")
    assert path.read_bytes() == b"two" and [p.name for p in path.parent.iterdir()] == ["dataset.json"]
    # shared data: the mode open() would give (not mkstemp's 0600)
    assert stat.S_IMODE(path.stat().st_mode) == FILE_MODE == 0o666 & ~_umask()


def test_a_failed_write_leaves_the_old_file(tmp_path):
    path = tmp_path / "index.npy"
    write_bytes_atomic(path, b"old")
    with pytest.raises(RuntimeError):
        with atomic_open(path) as f:
            f.write(b"half")
            raise RuntimeError("killed mid-write")
    assert path.read_bytes() == b"old" and len(list(tmp_path.iterdir())) == 1


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
