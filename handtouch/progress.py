"""A progress line every few seconds, whatever the run is doing (the smoke's heartbeat).

Loops report where they are through a callback (`Heartbeat.report`: a dict with
what / step / steps / samples_per_s; the trainer's `on_progress`, the RGB probes'
`progress`); a daemon thread prints, every `every_s` seconds, the current phase,
its elapsed time and the latest report of that phase with an ETA:

    smoke: train_vit 42 s: stage 1 step 120/200, 96 samples/s, ETA 25 s

Phases without a loop that reports (evaluation, the report) still get the phase
and its elapsed time, so a quiet stretch never lasts longer than `every_s`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


def describe(status: dict) -> str:
    """'stage 1 step 120/200, 96 samples/s, ETA 25 s' from a progress report."""
    parts = [f"{status.get('what', '')} step {status['step']}/{status['steps']}".strip()]
    sps = status.get("samples_per_s")
    if sps:
        parts.append(f"{sps:.0f} samples/s")
        steps_per_s = status.get("steps_per_s")
        if steps_per_s:
            parts.append(f"ETA {(status['steps'] - status['step']) / steps_per_s:.0f} s")
    return ", ".join(parts)


class Heartbeat:
    """See the module docstring. Use as a context manager; `phase(name)` when the run moves on."""

    def __init__(self, every_s: float = 5.0, emit: Callable[[str], None] | None = None, prefix: str = "smoke"):
        self.every_s = every_s
        self.emit = emit or (lambda line: print(line, flush=True))
        self.prefix = prefix
        self._lock = threading.Lock()
        self._phase, self._t_phase, self._status = "start", time.perf_counter(), None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="heartbeat", daemon=True)

    def phase(self, name: str) -> None:
        with self._lock:
            self._phase, self._t_phase, self._status = name, time.perf_counter(), None

    def report(self, status: dict) -> None:
        """The latest position of the current phase's loop (cheap: called every step)."""
        with self._lock:
            self._status = dict(status)

    def line(self) -> str:
        with self._lock:
            phase, elapsed, status = self._phase, time.perf_counter() - self._t_phase, self._status
        tail = f": {describe(status)}" if status else ""
        return f"{self.prefix}: {phase} {elapsed:.0f} s{tail}"

    def _loop(self) -> None:
        while not self._stop.wait(self.every_s):
            self.emit(self.line())

    def __enter__(self) -> "Heartbeat":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


class Rate:
    """Steps and samples per second since construction, for progress reports."""

    def __init__(self, first_step: int = 0):
        self.t0 = time.perf_counter()
        self.first_step = first_step

    def report(self, what: str, step: int, steps: int, batch: int) -> dict:
        """`step` steps of `steps` done, `batch` samples each (steps before first_step not timed here)."""
        dt = max(time.perf_counter() - self.t0, 1e-9)
        ran = step - self.first_step
        return {"what": what, "step": step, "steps": steps, "steps_per_s": ran / dt, "samples_per_s": ran * batch / dt}
