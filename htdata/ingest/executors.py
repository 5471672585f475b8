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

Ctrl-C: pool workers ignore SIGINT (a terminal sends it to the whole process
group: each worker would print its own traceback); the driver's
KeyboardInterrupt kills them (their unfinished units are redone by the re-run,
which resumes byte-identical, as after kill -9) and goes on up to the CLI,
which says it in one line.

Workers: how many is htdata/workers.py's (`resolve_workers`: not given = every usable core, 0 =
inline in this process, `InlineExecutor`). Threads: a worker runs `limit_threads(n)` before its
first unit, with n = usable cores // workers (at least 1): with 2 workers on 2 cores each uses
one thread in OpenCV (resize, JPEG), torch (if loaded) and OpenMP/BLAS,
instead of every worker starting a pool as wide as the machine. Ray tasks
(1 CPU each) use one thread. Video decoders are single-threaded anyway
(adapters/video.py).

Progress: a unit function may call `report_progress(event)` (a small dict,
e.g. one per finished episode). `map_units(fn, tasks, on_progress=cb)`
delivers those events to `cb` in the driver: inline directly, from a
process pool through a multiprocessing queue handed to each worker at
start-up. Ray tasks do not forward events (`report_progress` is a no-op
there): callers see progress only when a unit's result arrives.
"""

from __future__ import annotations

import importlib
import multiprocessing as mp
import os
import signal
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator

from htdata.errors import ArgumentError
from htdata.ingest.encodepool import THREADS_ENV
from htdata.workers import resolve_workers, usable_cores

EXECUTORS = ("process", "ray")


class UnitFailed(RuntimeError):
    """A unit kept failing after its retries."""


ProgressCallback = Callable[[dict], None]

# Where report_progress sends events in this process (None: nobody listens).
_progress_sink: ProgressCallback | None = None


def report_progress(event: dict) -> None:
    """Send a small progress event to the driver, if the executor running us listens."""
    if _progress_sink is not None:
        _progress_sink(event)


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Native threads each of `workers` processes may use so that together they fill the cores once."""
    cores = usable_cores() if cores is None else max(1, int(cores))
    return max(1, cores // max(1, int(workers)))


def limit_threads(threads: int) -> None:
    """Cap the native thread pools of this process at `threads`.

    OpenCV and an already imported torch are set directly; the OpenMP/BLAS
    variables only reach libraries loaded after this call, and a value the
    user exported is kept. The sample encoder (encodepool) gets `threads`
    threads, or none (inline) when the worker's share is one core.
    """
    n = max(1, int(threads))
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    os.environ.setdefault(THREADS_ENV, str(n if n > 1 else 0))   # sample encoding: threads only on spare cores
    try:
        import cv2
    except ImportError:  # pragma: no cover - cv2 is a dependency of htdata
        cv2 = None
    if cv2 is not None:
        cv2.setNumThreads(n)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)


_parent_pid: int | None = None


def die_with_parent(parent_pid: int) -> None:
    """A pool worker must not outlive the ingest that started it (kill -9 of the main process alone).

    Linux: the kernel SIGKILLs this process when its parent dies (prctl
    PR_SET_PDEATHSIG). Everywhere: `parent_alive()` is checked between
    episodes, and a parent already gone when this runs ends the worker now.
    """
    global _parent_pid
    _parent_pid = parent_pid
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):   # no prctl symbol: the between-episode check still applies
            pass
    if os.getppid() != parent_pid:
        os._exit(1)


def parent_alive() -> bool:
    """False in a pool worker whose parent (the ingest) has died; always True outside pool workers."""
    return _parent_pid is None or os.getppid() == _parent_pid


def _init_worker(queue, threads: int, parent_pid: int | None = None, preload: tuple[str, ...] = ()) -> None:
    """Process-pool initializer: die with the parent, thread caps, events go to the driver's queue, and the
    unit function's modules imported now (while the driver still plans), not on the first unit."""
    global _progress_sink
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # Ctrl-C is the driver's to handle (module docstring)
    if parent_pid is not None:
        die_with_parent(parent_pid)
    limit_threads(threads)
    if queue is not None:
        _progress_sink = queue.put
    for name in preload:
        importlib.import_module(name)


def _started() -> int:
    """The warm-up task: returns once this worker's initializer has run."""
    return os.getpid()


def _run_ray_unit(fn: Callable[[Any], Any], threads: int, task: Any) -> Any:
    """Body of one Ray task: a Ray worker is reused across tasks, so set the caps every time (cheap)."""
    limit_threads(threads)
    return fn(task)


def _drain(queue, on_progress: ProgressCallback) -> None:
    import queue as queue_module

    while True:
        try:
            event = queue.get_nowait()
        except (queue_module.Empty, EOFError, OSError):
            return
        on_progress(event)


class InlineExecutor:
    """Runs units one after another in this process (`--workers 0`: debugging, tests)."""

    def __init__(self, max_retries: int = 1):
        self.max_retries = max(0, int(max_retries))

    def start(self, preload: tuple[str, ...] = ()) -> None:
        """Nothing to start: units run in this process."""

    def close(self) -> None:
        """Nothing to stop."""

    def map_units(self, fn: Callable[[Any], Any], tasks: Iterable[Any],
                  on_progress: ProgressCallback | None = None) -> Iterator[tuple[Any, Any]]:
        global _progress_sink
        for task in tasks:
            for attempt in range(self.max_retries + 1):
                previous, _progress_sink = _progress_sink, on_progress
                try:
                    result = fn(task)
                    break
                except Exception as exc:
                    if attempt == self.max_retries:
                        raise UnitFailed(f"{task!r} failed after {attempt + 1} attempt(s): {exc}") from exc
                finally:
                    _progress_sink = previous
            yield task, result


class ProcessExecutor:
    """concurrent.futures process pool; keeps at most `2 * workers` tasks in flight.

    `start(preload)` spawns the workers and has them import `preload` while the caller goes on
    (an ingest plans meanwhile): spawning + importing takes ~0.5 s per worker, which otherwise
    sits between planning and the first unit. `map_units` starts the pool itself if nobody did,
    and shuts it down when its units are done (workers flush their last progress events as they
    exit, and those are delivered before it returns). `close()` shuts down a pool never used.
    """

    def __init__(self, workers: int | None = None, max_retries: int = 1, start_method: str = "spawn",
                 threads: int | None = None):
        self.workers = resolve_workers(workers)   # None: every usable core
        if self.workers == 0:
            raise ArgumentError("a process pool needs >= 1 worker; 0 workers run inline (InlineExecutor)")
        self.max_retries = max(0, int(max_retries))
        self.threads = threads_per_worker(self.workers) if threads is None else max(1, int(threads))
        # spawn: the parent may hold threads (tqdm monitor, BLAS) that fork would copy mid-lock.
        self.start_method = start_method
        self._pool = None
        self._queue = None

    def start(self, preload: tuple[str, ...] = ()) -> None:
        if self._pool is not None:
            return
        ctx = mp.get_context(self.start_method)
        self._queue = ctx.Queue()
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx, initializer=_init_worker,
                                         initargs=(self._queue, self.threads, os.getpid(), tuple(preload)))
        for _ in range(self.workers):   # one process per submit until the pool is full
            self._pool.submit(_started)

    def close(self, on_progress: ProgressCallback | None = None) -> None:
        pool, queue, self._pool, self._queue = self._pool, self._queue, None, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        if queue is not None:
            if on_progress is not None:
                _drain(queue, on_progress)   # the workers have exited: their last events are in
            queue.close()

    def map_units(self, fn: Callable[[Any], Any], tasks: Iterable[Any],
                  on_progress: ProgressCallback | None = None) -> Iterator[tuple[Any, Any]]:
        pending = list(tasks)
        pending.reverse()  # pop() from the end keeps submission in task order
        attempts: dict[int, int] = {}
        self.start()
        sink = on_progress or (lambda event: None)
        # Wake up a few times a second to forward progress events between unit results.
        timeout = 0.2 if on_progress is not None else None
        try:
            yield from self._run(fn, pending, attempts, self._pool, self._queue, sink, timeout)
        except KeyboardInterrupt:
            self._kill_workers()     # waiting for their units would make Ctrl-C wait minutes
            raise
        finally:
            self.close(sink)

    def _kill_workers(self) -> None:
        processes = getattr(self._pool, "_processes", None) or {}   # CPython's pool: {pid: Process}
        for proc in list(processes.values()):
            proc.kill()

    def _run(self, fn, pending, attempts, pool, queue, on_progress, timeout):
        running = {}
        while pending or running:
            while pending and len(running) < 2 * self.workers:
                task = pending.pop()
                running[pool.submit(fn, task)] = task
            done, _ = wait(running, timeout=timeout, return_when=FIRST_COMPLETED)
            _drain(queue, on_progress)  # before results, so a unit's events precede its completion
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

    `address=None` starts a local Ray with `workers` CPUs; "HOST:PORT" (the
    head's GCS, as `ray start --head` prints it), "auto" or "ray://host:port"
    joins a cluster. Every node must see the source and the dataset directory
    at the same path (shared filesystem): tasks write shards there and hash
    the sources they read (docs/USAGE.md "Scale-out").
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

    def start(self, preload: tuple[str, ...] = ()) -> None:
        """Ray starts (or joins) in map_units: a cluster is not started for an ingest with nothing to do."""

    def close(self) -> None:
        """map_units shuts down the Ray it started."""

    def _init(self) -> bool:
        """Connect/start Ray; True when this call started it (so we shut it down)."""
        if self.ray.is_initialized():
            return False
        kwargs: dict = {"include_dashboard": False, "log_to_driver": False}
        if self.address:
            kwargs["address"] = self.address
        else:
            # A local single-node Ray: keep it on loopback (no listening on the network).
            kwargs["_node_ip_address"] = "127.0.0.1"
            if self.workers:
                kwargs["num_cpus"] = int(self.workers)
        self.ray.init(**kwargs)
        return True

    def map_units(self, fn: Callable[[Any], Any], tasks: Iterable[Any],
                  on_progress: ProgressCallback | None = None) -> Iterator[tuple[Any, Any]]:
        """`on_progress` is accepted for a uniform interface; Ray tasks send no events.

        At most 2 x the cluster's CPUs tasks are in flight (submitted in the order given, the
        largest first): each `ray.wait` looks at those only, so a run of 10^5 units costs the driver
        O(units), not O(units^2) over a list of every unit still pending."""
        started = self._init()
        try:
            remote = self.ray.remote(max_retries=self.max_retries, retry_exceptions=True)(_run_ray_unit)
            pending = list(tasks)
            pending.reverse()   # pop() from the end keeps the given order
            in_flight = max(2, 2 * int(self.ray.cluster_resources().get("CPU", 1)))
            refs: dict = {}
            while pending or refs:
                while pending and len(refs) < in_flight:
                    task = pending.pop()
                    refs[remote.remote(fn, 1, task)] = task   # a Ray task holds 1 CPU
                self.ray.wait(list(refs), num_returns=1)                               # one is done ...
                ready, _ = self.ray.wait(list(refs), num_returns=len(refs), timeout=0)  # ... take all that are
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
    """The executor of `kind` with `workers` (htdata/workers.py: None = every usable core, 0 = inline)."""
    if kind not in EXECUTORS:
        raise ArgumentError(f"unknown executor {kind!r}; expected one of {EXECUTORS}")
    given = workers
    workers = resolve_workers(workers)
    if kind == "process":
        if address:
            raise ArgumentError("--address is only meaningful with --executor ray")
        if workers == 0:
            return InlineExecutor(max_retries=max_retries)
        return ProcessExecutor(workers, max_retries=max_retries)
    if given == 0:
        raise ArgumentError("--workers 0 runs units inline, in this process; Ray runs them on its workers: give "
                            "--workers N (N >= 1: a local Ray's CPUs) or leave it out (every usable core)")
    # a local Ray gets the workers as its CPUs; a cluster (address) has its own
    return RayExecutor(address=address, workers=workers, max_retries=max_retries)
