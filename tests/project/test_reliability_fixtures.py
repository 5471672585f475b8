"""The `spawn` fixture (tests/conftest.py) kills what a FAILING test started, its whole process group.

Before issue 18, test_pool_workers_die_when_the_main_process_is_killed killed its hung ingest only on
the success path; under load it once failed and left `htdata ingest` hanging for an hour.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import psutil

INNER = '''
import subprocess, sys
from pathlib import Path

def test_fails_while_its_child_and_grandchild_hang(spawn):
    # The grandchild says it runs by writing a file; the test fails only once it exists (no sleep-and-hope).
    grandchild = "import pathlib, time; pathlib.Path('started').write_text('1'); time.sleep(600)"
    code = f"import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', {grandchild!r}]); time.sleep(600)"
    proc = spawn([sys.executable, "-c", code])
    Path("pid").write_text(str(proc.pid))
    import time
    deadline = time.monotonic() + 120
    while not Path("started").exists():
        assert time.monotonic() < deadline, "the grandchild never started"
        time.sleep(0.02)
    assert False, "this inner test fails on purpose"
'''


def _session(pid):
    try:
        return os.getsid(pid)
    except OSError:
        return None


def test_spawn_kills_the_process_group_of_a_failing_test(tmp_path):
    shutil.copyfile(Path(__file__).resolve().parents[1] / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_inner.py").write_text(INNER)
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
                          "--rootdir", str(tmp_path), str(tmp_path / "test_inner.py")],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 1 and "fails on purpose" in res.stdout, res.stdout + res.stderr
    assert (tmp_path / "started").exists()   # the grandchild ran before the inner test failed
    pid = int((tmp_path / "pid").read_text())
    left = [p for p in psutil.process_iter(["pid", "status"])   # only the inner test's session; a killed
            if _session(p.pid) == pid and p.info["status"] != psutil.STATUS_ZOMBIE]   # one awaiting reaping is dead
    for p in left:                 # never leak from this test either
        p.kill()
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    assert left == []
