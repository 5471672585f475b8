"""Run the same per-unit function locally (process pool) or on a Ray cluster.

Both executors take a picklable top-level function and a list of small task
objects, and yield `(task, result)` pairs as units finish (any order). Results
must be small records (shard/sample/episode records): decoded frames never
travel between processes; workers write shards straight to the dataset
directory, so the function must be idempotent per unit (it is: a unit clears
its own shards before writing).

Retries are bounded: an exception raised by the function is retried up to
`max_retries` times, then re-raised. A worker process that dies (killed,
os._exit) breaks a local pool: the run stops and a re-run resumes.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator

EXECUTORS = ("process", "ray")


class UnitFailed(RuntimeError):
    """A unit kept failing after its retries."""


class InlineExecutor:
    """Runs units one after another in this process (`--workers 0`: debugging, tests)."""

    def __init__(self, max_retries: int = 1):
        self.max_retries = max(0, int(max_retries))

    def map_units(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
        for task in tasks:
            for attempt in range(self.max_retries + 1):
                try:
                    result = fn(task)
                    break
                except Exception as exc:
                    if attempt == self.max_retries:
                        raise UnitFailed(f"{task!r} failed after {attempt + 1} attempt(s): {exc}") from exc
            yield task, result


class ProcessExecutor:
    """concurrent.futures process pool; keeps at most `2 * workers` tasks in flight."""

    def __init__(self, workers: int | None = None, max_retries: int = 1, start_method: str = "spawn"):
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self.max_retries = max(0, int(max_retries))
        # spawn: the parent may hold threads (tqdm monitor, BLAS) that fork would copy mid-lock.
        self.start_method = start_method

    def map_units(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
        pending = list(tasks)
        pending.reverse()  # pop() from the end keeps submission in task order
        attempts: dict[int, int] = {}
        ctx = mp.get_context(self.start_method)
        with ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx) as pool:
            running = {}
            while pending or running:
                while pending and len(running) < 2 * self.workers:
                    task = pending.pop()
                    running[pool.submit(fn, task)] = task
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in done:
                    task = running.pop(fut)
                    exc = fut.exception()
                    if exc is None:
                        yield task, fut.result()
                        continue
                    from concurrent.futures.process import BrokenProcessPool

                    if isinstance(exc, BrokenProcessPool):
                        raise UnitFailed(f"a worker process died while running {task!r}; "
                                         f"re-run the same command to resume") from exc
                    n = attempts.get(id(task), 0) + 1
                    attempts[id(task)] = n
                    if n > self.max_retries:
                        raise UnitFailed(f"{task!r} failed after {n} attempt(s): {exc}") from exc
                    running[pool.submit(fn, task)] = task


class RayExecutor:
    """Ray tasks, one per unit, with Ray's own bounded retries (`max_retries`).

    `address=None` starts a local Ray with `workers` CPUs; "auto" or
    "ray://host:port" joins a cluster. Every node must see the source and the
    dataset directory at the same path (shared filesystem).
    """

    def __init__(self, address: str | None = None, workers: int | None = None, max_retries: int = 2):
        try:
            import ray
        except ImportError as e:  # pragma: no cover - ray is installed in the project venv
            raise RuntimeError("--executor ray needs the `ray` package: pip install 'htdata[ray]'") from e
        self.ray = ray
        self.address = address
        self.workers = workers
        self.max_retries = max(0, int(max_retries))

    def _init(self) -> bool:
        """Connect/start Ray; True when this call started it (so we shut it down)."""
        if self.ray.is_initialized():
            return False
        kwargs: dict = {"include_dashboard": False, "log_to_driver": False}
        if self.address:
            kwargs["address"] = self.address
        elif self.workers:
            kwargs["num_cpus"] = int(self.workers)
        self.ray.init(**kwargs)
        return True

    def map_units(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
        started = self._init()
        try:
            remote = self.ray.remote(max_retries=self.max_retries, retry_exceptions=True)(fn)
            refs = {remote.remote(task): task for task in tasks}
            while refs:
                ready, _ = self.ray.wait(list(refs), num_returns=1)
                for ref in ready:
                    task = refs.pop(ref)
                    try:
                        result = self.ray.get(ref)
                    except Exception as e:
                        raise UnitFailed(f"{task!r} failed on Ray after {self.max_retries} retries: {e}") from e
                    yield task, result
        finally:
            if started:
                self.ray.shutdown()


def make_executor(kind: str, workers: int | None = None, address: str | None = None,
                  max_retries: int = 1):
    if kind == "process":
        if address:
            raise ValueError("--address is only meaningful with --executor ray")
        if workers == 0:
            return InlineExecutor(max_retries=max_retries)
        return ProcessExecutor(workers, max_retries=max_retries)
    if kind == "ray":
        return RayExecutor(address=address, workers=workers, max_retries=max_retries)
    raise ValueError(f"unknown executor {kind!r}; expected one of {EXECUTORS}")
