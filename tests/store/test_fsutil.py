"""Atomic writes (htdata/fileio.py): content replaced whole, temp files gone, files readable like any other;
the store's sha256_file, and the old names of the writes under htdata.store.fsutil."""

import hashlib
import importlib
import io
import json
import os
import stat
import warnings

import pytest

from htdata import fileio
from htdata.fileio import (
    FILE_MODE,
    atomic_open,
    sha256_stream,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
)
from htdata.store.fsutil import sha256_file


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


def test_text_and_json_writes_are_utf8_with_a_final_newline(tmp_path):
    write_text_atomic(tmp_path / "results.md", "F\u2013 \u00e9\n")
    write_json_atomic(tmp_path / "results.json", {"b": 1, "a": "\u00e9"}, sort_keys=True)
    assert (tmp_path / "results.md").read_bytes() == "F\u2013 \u00e9\n".encode("utf-8")
    assert (tmp_path / "results.json").read_text("utf-8") == '{\n  "a": "\\u00e9",\n  "b": 1\n}\n'
    assert json.loads((tmp_path / "results.json").read_text()) == {"a": "\u00e9", "b": 1}


def test_sha256_of_a_stream_and_of_a_stored_file_agree_with_hashlib(tmp_path):
    data = os.urandom(3 * 1024 + 7)
    (tmp_path / "shard.tar").write_bytes(data)
    want = hashlib.sha256(data).hexdigest()
    assert sha256_stream(io.BytesIO(data), chunk=1000) == want       # several chunks, a short last one
    assert sha256_file(tmp_path / "shard.tar") == want == sha256_file(str(tmp_path / "shard.tar"), chunk=64)
    assert sha256_stream(io.BytesIO(b"")) == hashlib.sha256(b"").hexdigest()


@pytest.mark.parametrize("name", ["atomic_open", "write_bytes_atomic", "write_json_atomic", "FILE_MODE"])
def test_the_old_names_under_the_store_warn_and_are_the_same_object(name):
    fsutil = importlib.import_module("htdata.store.fsutil")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = getattr(fsutil, name)
    assert value is getattr(fileio, name)
    assert [w.category for w in caught] == [DeprecationWarning] and f"htdata.fileio.{name}" in str(caught[0].message)
