"""A progress line every few seconds, whatever the run is doing (the smoke's heartbeat).

Loops report where they are through a callback (`Heartbeat.report`: a dict with
what / step / steps / samples_per_s, and steps_after, the steps of the phase's later
loops; the trainer's `on_progress`, the RGB probes' `progress`); a daemon thread
prints, every `every_s` seconds, the current phase,
its elapsed time and the latest report of that phase with an ETA:

    smoke: train_vit 42 s: stage 1 step 120/200, 96 samples/s, ETA 25 s

Phases without a loop that reports (evaluation, the report) still get the phase
and its elapsed time, so a quiet stretch never lasts longer than `every_s`.

With a `RunPlan` (the seconds each phase is expected to take, in run order) every
line also ends with the ETA of the whole run, not only of the current loop:

    smoke: train_vit 42 s: stage 1 step 120/200, 96 samples/s, ETA 25 s; run 150 s in, ETA ~190 s

The run's ETA is the current phase's rest (the longer of the loop's ETA and what the
plan leaves of the phase) plus the later phases' expected seconds, all scaled by how
fast this run has been so far: the ratio of measured to expected seconds over the
finished phases the plan marks as timed, and the running one once it is over its time
(cache-dependent phases such as building data, which take ~0 s when reused, are not
timed: they would say nothing about speed).

`PhaseTimer` runs a script's phases one after another, names each to the heartbeat and
keeps its wall seconds (the smoke's and `make compare`'s meta.seconds).
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


def loop_eta(status: dict | None) -> float | None:
    """Seconds left in the reporting loop and the loops of its phase still to come (a report's
    `steps_after`: the trainer's later stages, the probes not trained yet), at the loop's rate."""
    if not status or not status.get("steps_per_s"):
        return None
    return (max(status["steps"] - status["step"], 0) + status.get("steps_after", 0)) / status["steps_per_s"]


def with_steps_after(progress: Callable[[dict], None] | None, steps_after: int) -> Callable[[dict], None] | None:
    """`progress` with `steps_after` (the steps of this phase's later loops) added to every report."""
    if progress is None:
        return None
    return lambda status: progress({**status, "steps_after": steps_after})


# The run's speed factor starts from 1 as if SPEED_PRIOR_S seconds had gone as planned (so a 1 s phase
# that took 3 s does not triple the ETA), and is kept within SPEED_BOUNDS.
SPEED_PRIOR_S = 30.0
SPEED_BOUNDS = (0.25, 8.0)


class RunPlan:
    """Expected seconds per phase, in run order, and the phases finished so far (module docstring).

    expected: {phase: seconds}; untimed: phases whose time depends on a cache (excluded from the speed).
    """

    def __init__(self, expected: dict[str, float], untimed: tuple[str, ...] = ()):
        self.expected = {k: max(float(v), 0.0) for k, v in expected.items()}
        self.untimed = set(untimed)
        self.done: dict[str, float] = {}

    def expect(self, phase: str, seconds: float) -> None:
        """Change a phase's expected seconds (e.g. 0 once its output is known to be cached)."""
        self.expected[phase] = max(float(seconds), 0.0)

    def finished(self, phase: str, seconds: float) -> None:
        self.done[phase] = self.done.get(phase, 0.0) + seconds

    def speed(self, phase: str | None = None, elapsed: float = 0.0) -> float:
        """Measured / expected seconds over the finished timed phases, with SPEED_PRIOR_S on each side;
        the running `phase` counts too once it has run over its expected seconds (`elapsed`)."""
        timed = [p for p in self.done if p not in self.untimed and self.expected.get(p, 0.0) > 0]
        measured = sum(self.done[p] for p in timed) + SPEED_PRIOR_S
        expected = sum(self.expected[p] for p in timed) + SPEED_PRIOR_S
        planned = self.expected.get(phase, 0.0)
        if phase not in self.untimed and phase not in self.done and 0.0 < planned < elapsed:
            measured, expected = measured + elapsed, expected + planned
        return min(max(measured / expected, SPEED_BOUNDS[0]), SPEED_BOUNDS[1])

    def remaining(self, phase: str, elapsed: float, loop_left: float | None = None) -> float:
        """Seconds left in the run: the rest of `phase` (`elapsed` s in) and every later unfinished phase."""
        speed = self.speed(phase, elapsed)
        names = list(self.expected)
        later = names[names.index(phase) + 1:] if phase in self.expected else names
        rest = max(self.expected.get(phase, 0.0) * speed - elapsed, loop_left or 0.0, 0.0)
        return rest + speed * sum(self.expected[p] for p in later if p not in self.done and p != phase)


class Heartbeat:
    """See the module docstring. Use as a context manager; `phase(name)` when the run moves on."""

    def __init__(self, every_s: float = 5.0, emit: Callable[[str], None] | None = None, prefix: str = "smoke",
                 plan: RunPlan | None = None, clock: Callable[[], float] = time.perf_counter):
        self.every_s = every_s
        self.emit = emit or (lambda line: print(line, flush=True))
        self.prefix = prefix
        self.plan = plan
        self.clock = clock
        self._lock = threading.Lock()
        self._t0 = clock()
        self._phase, self._t_phase, self._status = "start", self._t0, None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="heartbeat", daemon=True)

    def phase(self, name: str) -> None:
        with self._lock:
            now = self.clock()
            if self.plan is not None and self._phase != "start":
                self.plan.finished(self._phase, now - self._t_phase)
            self._phase, self._t_phase, self._status = name, now, None

    def report(self, status: dict) -> None:
        """The latest position of the current phase's loop (cheap: called every step)."""
        with self._lock:
            self._status = dict(status)

    def line(self) -> str:
        with self._lock:
            now = self.clock()
            phase, elapsed, status = self._phase, now - self._t_phase, self._status
            run = ""
            if self.plan is not None:
                left = self.plan.remaining(phase, elapsed, loop_eta(status))
                run = f"; run {now - self._t0:.0f} s in, ETA ~{left:.0f} s"
        tail = f": {describe(status)}" if status else ""
        return f"{self.prefix}: {phase} {elapsed:.0f} s{tail}{run}"

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


class PhaseTimer:
    """Wall seconds per named phase, in run order; each phase named to the heartbeat as it starts."""

    def __init__(self, heartbeat: Heartbeat | None = None):
        self.seconds: dict[str, float] = {}
        self.t0 = time.perf_counter()
        self.heartbeat = heartbeat

    def run(self, name: str, fn, *args, **kwargs):
        if self.heartbeat is not None:
            self.heartbeat.phase(name)
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t

    def total(self) -> dict[str, float]:
        return {**self.seconds, "total": time.perf_counter() - self.t0}
