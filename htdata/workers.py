"""How many worker processes a command runs: the one reading of every `--workers` (ingest and its
executors, validate).

One meaning everywhere:
- not given (None): the command's default, counted in the cores this process may run on
  (`usable_cores`: the affinity mask a container, `taskset` or a batch scheduler sets, not the
  machine's count): ingest uses them all; validate all with `--deep`, else none;
- 0: no worker process: the work runs inline, in this process (debugging, profiling, tests);
- N >= 1: N worker processes (validate runs one worker's share inline: a pool of one would only add
  a process). Ray's workers are its CPUs; Ray cannot run inline, so `--executor ray --workers 0` is
  refused;
- below 0: an ArgumentError naming the option.

A worker's native threads (OpenCV, BLAS, the sample encoder) come from its share of the same cores
(htdata/ingest/executors.py `threads_per_worker`).
"""

from __future__ import annotations

import os

from htdata.errors import ArgumentError


def usable_cores() -> int:
    """Cores this process may run on (its affinity mask where the OS exposes one), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def resolve_workers(requested: int | None, default: int | None = None, option: str = "--workers") -> int:
    """The worker processes to run: `requested`, or `default` (None: `usable_cores()`) when not given;
    0 = inline, in this process.

    Args:
        requested: what the user asked for (None: not given).
        default: the command's count when not given (None: every usable core).
        option: the option an error names.

    Raises:
        ArgumentError: `requested` below 0 or not a whole number.
    """
    if requested is None:
        return usable_cores() if default is None else max(0, int(default))
    if isinstance(requested, bool) or int(requested) != requested:
        raise ArgumentError(f"{option} must be a whole number >= 0, got {requested!r}")
    if requested < 0:
        raise ArgumentError(f"{option} must be >= 0 (0: run in this process, no worker process), got {requested}")
    return int(requested)
