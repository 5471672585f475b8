"""Shared fixtures.

`spawn`: start a subprocess in its own process group (session) and kill that whole group when the test
ends, passed or failed, so a test that stops early never leaves a hung `htdata` (or its pool workers)
running. Use it for every subprocess a test does not run to completion itself.
"""

from __future__ import annotations

import os
import signal
import subprocess

import pytest


@pytest.fixture
def spawn():
    started: list[subprocess.Popen] = []

    def start(cmd, **kw) -> subprocess.Popen:
        proc = subprocess.Popen(cmd, start_new_session=True, **kw)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        try:
            os.killpg(proc.pid, signal.SIGKILL)   # the group outlives its leader: workers of a killed main too
        except ProcessLookupError:
            pass
        if proc.poll() is None:
            proc.wait(timeout=30)
