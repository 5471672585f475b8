"""Writer lock: one writer per dataset, stale locks taken over, foreign hosts respected."""

import json
import multiprocessing as mp
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from htdata.store.lock import LOCK_FILE, DatasetLocked, WriterLock


def write_lock(root, **holder):
    base = {"host": socket.gethostname(), "pid": os.getpid(), "pid_start": None, "started": "t0",
            "command": "htdata ingest ..."}
    (root / LOCK_FILE).write_text(json.dumps({**base, **holder}))


def test_lock_is_exclusive_and_released(tmp_path):
    with WriterLock(tmp_path, "first") as lock:
        assert lock.note is None
        holder = json.loads((tmp_path / LOCK_FILE).read_text())
        assert holder["pid"] == os.getpid() and holder["command"] == "first"
        with pytest.raises(DatasetLocked, match=f"pid {os.getpid()}.*first"):
            WriterLock(tmp_path, "second").acquire()
    assert not (tmp_path / LOCK_FILE).exists()
    with WriterLock(tmp_path, "third"):   # free again
        pass


def test_live_holder_in_another_process_is_refused(tmp_path):
    code = ("import sys,time; from htdata.store.lock import WriterLock; "
            "l=WriterLock(sys.argv[1],'sleeper').acquire(); print('held', flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        with pytest.raises(DatasetLocked, match=f"pid {proc.pid}.*sleeper"):
            WriterLock(tmp_path).acquire()
    finally:
        proc.kill()
        proc.wait()
    # killed without releasing (kill -9): the lock is stale now and is taken over with a note
    with WriterLock(tmp_path, "after") as lock:
        assert "no longer running" in lock.note and str(proc.pid) in lock.note


def test_dead_pid_and_garbled_lock_are_stale(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    write_lock(tmp_path, pid=int(dead))
    with WriterLock(tmp_path) as lock:
        assert "no longer running" in lock.note
    (tmp_path / LOCK_FILE).write_text('{"host": "x", "pi')     # writer killed mid-write
    with WriterLock(tmp_path) as lock:
        assert "unreadable lock file" in lock.note


def test_reused_pid_is_stale(tmp_path):
    # our own pid, but recorded with another process start time: the pid was reused
    write_lock(tmp_path, pid_start=1.0)
    with WriterLock(tmp_path) as lock:
        assert "no longer running" in lock.note


def test_other_host_is_never_broken(tmp_path):
    write_lock(tmp_path, host="some-other-host", pid=1)
    with pytest.raises(DatasetLocked, match="another host.*remove .*lock by hand"):
        WriterLock(tmp_path).acquire()
    assert json.loads((tmp_path / LOCK_FILE).read_text())["host"] == "some-other-host"


def _race(root, barrier, results, done):
    barrier.wait()
    try:
        lock = WriterLock(root, f"racer {os.getpid()}").acquire()
        results.put("won")
        done.wait(30)            # hold the lock until every racer has tried (however slow the machine)
        lock.release()
    except DatasetLocked:
        results.put("refused")


def race(root, racers: int = 4) -> list[str]:
    """Start `racers` processes that try to lock `root` at once; the winner holds until all have tried."""
    ctx = mp.get_context("fork")
    barrier, results, done = ctx.Barrier(racers), ctx.Queue(), ctx.Event()
    procs = [ctx.Process(target=_race, args=(root, barrier, results, done)) for _ in range(racers)]
    for p in procs:
        p.start()
    outcomes = sorted(results.get(timeout=30) for _ in procs)
    done.set()
    for p in procs:
        p.join(30)
    return outcomes


def test_concurrent_writers_one_wins(tmp_path):
    assert race(tmp_path) == ["refused", "refused", "refused", "won"]


def test_racing_takeovers_of_a_stale_lock_one_wins(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    for _ in range(5):
        write_lock(tmp_path, pid=int(dead))
        assert race(tmp_path) == ["refused", "refused", "refused", "won"]
        assert not (tmp_path / LOCK_FILE).exists()


def test_a_cleanup_keeps_the_temp_file_a_racing_writer_takes_the_lock_with(tmp_path, monkeypatch):
    """CI caught it: merge and ingest cleanups removed `*.tmp` except names starting '.lock', but the lock's
    temp file is '..lock.PID.tmp' (fileio.write_bytes_exclusive), so a writer racing for the lock lost its
    temp file between write and link and failed with a raw ENOENT."""
    from htdata import fileio
    from htdata.ingest.workdir import remove_strays
    from htdata.store.lock import LOCK_FILE, WriterLock, is_lock_file

    seen = []

    def link_later(src, dst):              # the name the real writer uses, captured mid-race
        seen.append(Path(src).name)
        raise FileExistsError(dst)

    monkeypatch.setattr(fileio.os, "link", link_later)
    (tmp_path / LOCK_FILE).write_text("{}")
    assert WriterLock(tmp_path)._try_create() is False
    monkeypatch.undo()
    assert seen and is_lock_file(seen[0])
    racing = tmp_path / seen[0]
    racing.write_text("lock record being written")
    other = tmp_path / ".index.json.123.tmp"
    other.write_text("left by a kill")
    remove_strays(tmp_path, [], first_unit=0)
    assert racing.exists() and not other.exists()
