"""Worker counts (htdata/workers.py: one meaning of --workers) and thread caps: each worker fills its share of
the cores once, never more."""

from __future__ import annotations

import cv2
import pytest

from htdata.errors import ArgumentError
from htdata.ingest import executors
from htdata.ingest.executors import InlineExecutor, ProcessExecutor, limit_threads, make_executor, threads_per_worker
from htdata.workers import resolve_workers, usable_cores


def test_threads_per_worker_splits_cores():
    assert threads_per_worker(1, cores=2) == 2
    assert threads_per_worker(2, cores=2) == 1
    assert threads_per_worker(3, cores=2) == 1      # never 0
    assert threads_per_worker(2, cores=8) == 4
    assert threads_per_worker(0, cores=4) == 4      # 0 workers (inline) counts as one
    assert executors.usable_cores() >= 1


def test_workers_have_one_meaning(monkeypatch):
    """htdata/workers.py: not given = the usable cores (the affinity mask, not the machine's count), 0 = inline,
    below 0 an error naming the option; the executors and validate read it, nothing counts cores itself."""
    import htdata.workers as workers_module

    monkeypatch.setattr(workers_module.os, "sched_getaffinity", lambda pid: {0, 3, 5})
    monkeypatch.setattr(workers_module.os, "cpu_count", lambda: 64)
    assert usable_cores() == 3 and resolve_workers(None) == 3 and resolve_workers(None, default=0) == 0
    assert resolve_workers(0) == 0 and resolve_workers(2) == 2
    for bad in (-1, 1.5):
        with pytest.raises(ArgumentError, match="--workers must be"):
            resolve_workers(bad)
    assert isinstance(make_executor("process", 0), InlineExecutor)
    pool = make_executor("process", None)
    assert isinstance(pool, ProcessExecutor) and pool.workers == 3 and pool.threads == 1
    assert ProcessExecutor().workers == 3
    with pytest.raises(ArgumentError, match="0 workers run inline"):
        ProcessExecutor(workers=0)
    with pytest.raises(ArgumentError, match="--workers must be >= 0"):
        make_executor("process", -2)
    with pytest.raises(ArgumentError, match="--workers 0 runs units inline"):
        make_executor("ray", 0)


def test_limit_threads_sets_opencv_and_keeps_user_env(monkeypatch):
    before = cv2.getNumThreads()
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    try:
        limit_threads(1)
        assert cv2.getNumThreads() == 1
        import os
        assert os.environ["OMP_NUM_THREADS"] == "7"          # the user's choice stays
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
        limit_threads(0)                                     # clamped to 1
        assert cv2.getNumThreads() == 1
    finally:
        cv2.setNumThreads(before)


def _worker_threads(_task) -> tuple[int, str]:
    import os

    return cv2.getNumThreads(), os.environ.get("OPENBLAS_NUM_THREADS", "")


def test_process_pool_workers_get_their_share(monkeypatch):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    pool = ProcessExecutor(workers=2, threads=1)
    results = [r for _, r in pool.map_units(_worker_threads, [0, 1])]
    assert results == [(1, "1"), (1, "1")]
    assert ProcessExecutor(workers=2).threads == threads_per_worker(2)


def test_inline_executor_leaves_threads_alone():
    before = cv2.getNumThreads()
    assert [r for _, r in InlineExecutor().map_units(_worker_threads, [0])][0][0] == before


def test_ray_task_body_caps_threads():
    before = cv2.getNumThreads()
    try:
        assert executors._run_ray_unit(_worker_threads, 1, None)[0] == 1
    finally:
        cv2.setNumThreads(before)


def test_bad_threads_argument():
    with pytest.raises((TypeError, ValueError)):
        ProcessExecutor(workers=1, threads="many")


def _which_modules(_task) -> bool:
    import sys

    return "colorsys" in sys.modules      # a stdlib module nothing here imports


def _report_then_return(task):
    executors.report_progress({"task": task})
    return task


def test_started_pool_preloads_and_still_delivers_every_progress_event():
    """start() spawns the workers with the unit code imported; a unit's events all reach the driver."""
    pool = ProcessExecutor(workers=2, threads=1)
    pool.start(preload=("colorsys",))
    assert all(r for _, r in pool.map_units(_which_modules, [0, 1]))
    assert not any(r for _, r in ProcessExecutor(workers=1, threads=1).map_units(_which_modules, [0]))
    events = []
    pool.start()
    results = sorted(r for _, r in pool.map_units(_report_then_return, list(range(6)), on_progress=events.append))
    assert results == list(range(6)) and sorted(e["task"] for e in events) == list(range(6))
    pool.close()                                  # nothing running: a no-op
    InlineExecutor().start(preload=("htdata.ingest.unit",))
