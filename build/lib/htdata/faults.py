"""Named crash points for the kill -9 tests of every writer.

`crash_point("name")` does nothing unless HTDATA_TEST_CRASH_AT=name is set,
in which case the process dies at once with os._exit(137), as kill -9 would
leave it: no finally blocks, no atexit, files half written as they are.
Tests run a command in a subprocess with each point set, then check that
the committed versions still read and validate and that a re-run gives the
same dataset as a run that never crashed.
"""

from __future__ import annotations

import os

ENV = "HTDATA_TEST_CRASH_AT"


def crash_point(name: str) -> None:
    if os.environ.get(ENV) == name:
        os._exit(137)
