"""Issue 35 rough edges: one line naming the file for an index header declaring 1e11 rows and for a
leftover `.lock.takeover` (a bare mmap ValueError and an unnamed "contended" before)."""

from __future__ import annotations

import hashlib
import io
import json
import os
import socket
import subprocess
import sys
import time

import pytest

import htdata
from htdata.cli import main as cli_main
from htdata.errors import DatasetError
from htdata.store.lock import LOCK_FILE, DatasetLocked, WriterLock
from htdata.validate import validate_dataset
from tests.factories import SPLIT_EPISODES as EPISODES
from tests.factories import rewrite_manifest, write_synthetic_dataset
from tests.factories.legacy import as_format3


def _forge_index_rows(root, rows: int, stored_as: str) -> None:
    """Rewrite an index file's header to declare `rows` rows (data unchanged), re-sealed in the manifest: the
    current version's index.npy (format 3) or its first segment's rows (format 4)."""
    from numpy.lib import format as npy

    manifest = json.loads((root / "dataset.json").read_text())
    entry = manifest["segments"][0] if stored_as == "segments" else manifest
    path = root / entry["index" if stored_as == "segments" else "index_file"]
    data = path.read_bytes()
    f = io.BytesIO(data)
    npy.read_magic(f)
    _, _, dtype = npy.read_array_header_1_0(f)
    head = io.BytesIO()
    npy.write_array_header_1_0(head, {"descr": npy.dtype_to_descr(dtype), "fortran_order": False, "shape": (rows,)})
    assert len(head.getvalue()) == f.tell()          # same header length: the rows stay where they were
    path.write_bytes(head.getvalue() + data[f.tell():])
    entry["index_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    rewrite_manifest(root, manifest)


@pytest.mark.parametrize("stored_as", ["index.npy", "segments"])
def test_an_index_header_declaring_1e11_rows_is_one_line_naming_the_file(tmp_path, capsys, stored_as):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES[:2])
    if stored_as == "index.npy":
        as_format3(root)
    _forge_index_rows(root, 10**11, stored_as)
    said = r"\.npy: index header declares 100000000000 rows of \d+ bytes but the file holds \d+ bytes"
    with pytest.raises(DatasetError, match=said):
        htdata.open(root).sample(0)
    report = validate_dataset(root)
    assert not report["ok"] and any("declares 100000000000 rows" in f["message"]
                                    for f in report["checks"]["structure"]["failures"])
    capsys.readouterr()
    assert cli_main(["stats", str(root), "--brief"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "declares 100000000000 rows" in err[0], err


def _stale_lock(root) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    (root / LOCK_FILE).write_text(json.dumps({"host": socket.gethostname(), "pid": int(dead), "pid_start": None,
                                              "started": "t0", "command": "killed writer"}))


def test_a_leftover_takeover_mutex_is_named(tmp_path):
    _stale_lock(tmp_path)
    mutex = tmp_path / f"{LOCK_FILE}.takeover"
    mutex.write_text("")                          # fresh: another writer could be inside its takeover
    with pytest.raises(DatasetLocked, match=rf"{mutex}: a takeover of the stale writer lock .* is under way or "
                                            rf"was left by a writer killed inside it"):
        WriterLock(tmp_path, "second").acquire()
    future = time.time() + 10 * 86400             # dated in the future: no live writer wrote it just now
    os.utime(mutex, (future, future))
    with WriterLock(tmp_path, "third") as lock:
        assert "took over a stale lock" in lock.note and not mutex.exists()
    _stale_lock(tmp_path)
    mutex.mkdir()
    with pytest.raises(DatasetLocked, match=rf"{mutex}: a directory \(or another non-file\) where the writer "
                                            rf"lock's takeover mutex goes"):
        WriterLock(tmp_path, "fourth").acquire()
