"""Issue 35 rough edges of the ingest: Ctrl-C is one line, a first ingest that fits nothing leaves no
skeleton, and a machine failure (ENOSPC) recorded during an append is retried by the next run, not replayed."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from htdata.store.manifest import load_episodes
from htdata.store.versions import list_versions
from tests.factories import ingest_cli, make_native, make_opentouch, make_touchanything

ROOT = Path(__file__).resolve().parents[2]


def test_ctrl_c_during_an_ingest_is_one_line_saying_how_to_resume(tmp_path, spawn):
    raw = make_opentouch(tmp_path / "raw")
    out = tmp_path / "ds"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HTDATA_TEST_FAULT_UNIT": "0", "HTDATA_TEST_FAULT": "hang"}
    proc = spawn([sys.executable, "-m", "htdata.cli", "ingest", "--workers", "2", "--quiet",
                  "--pipeline", "opentouch", str(raw), str(out)], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not list((out / "shards").glob(".shard-000000-*.tmp")):    # unit 0 is inside its first episode
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGINT)       # what a terminal's Ctrl-C does: the whole process group
    err = proc.communicate(timeout=120)[1]
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 130 and len(lines) == 1, err
    assert lines[0].startswith("htdata ingest: interrupted (Ctrl-C); run the same command again to resume")
    assert not (out / ".lock").exists()
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 0 and list_versions(out) == [1]


def test_a_folder_of_another_format_says_so_before_any_label_table(tmp_path, capsys):
    """A TouchAnything folder given to the OpenTouch pipeline: the first line is that no OpenTouch HDF5 is
    there and which pipeline fits, not that OpenTouch's label table is missing (whose fix led nowhere)."""
    raw = make_touchanything(tmp_path / "raw")
    assert ingest_cli("--pipeline", "opentouch", raw, tmp_path / "ds") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no OpenTouch HDF5 scene files (*.hdf5) under" in err, err
    assert "--pipeline touchanything" in err and "annotation" not in err and "%|" not in err, err


def test_a_first_ingest_whose_pipeline_fits_nothing_leaves_no_skeleton(tmp_path, capsys):
    raw = make_opentouch(tmp_path / "raw")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, out) == 2
    err = capsys.readouterr().err   # what is missing, and what the folder holds instead
    assert "no native recordings (recording.json) under" in err and "OpenTouch HDF5 scene files (*.hdf5): " \
        "--pipeline opentouch" in err, err
    assert not out.exists()
    out.mkdir()                                   # an empty folder given: left as it was, empty
    assert ingest_cli("--pipeline", "native", raw, out) == 2
    assert out.is_dir() and not list(out.iterdir())


def test_an_enospc_episode_failure_of_an_append_is_retried_by_the_next_run(tmp_path, monkeypatch, capsys):
    from htdata.ingest import unit

    raw = make_native(tmp_path / "raw")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, out) == 0
    shutil.copytree(raw / "rec_good", raw / "rec_more")
    real_add = unit.Spool.add

    def full_disk(self, key, members):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(unit.Spool, "add", full_disk)
    assert ingest_cli("--pipeline", "native", raw, out) == 1
    assert "[nat-rec_more]: OSError: [Errno 28] No space left on device" in capsys.readouterr().err
    [record] = [json.loads(p.read_text()) for p in (out / ".work").glob("unit-*.json")]
    assert record["failures"][0]["retry"] is True
    monkeypatch.setattr(unit.Spool, "add", real_add)   # space again: the episode is ingested, not replayed
    assert ingest_cli("--pipeline", "native", raw, out) == 0
    assert sorted(e["episode_id"] for e in load_episodes(out)) == ["nat-rec_good", "nat-rec_more"]
    assert list_versions(out) == [1, 2]
