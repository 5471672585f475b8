"""The smoke's progress lines: the ETA of the whole run, not only of the current loop (handtouch/progress.py)."""

import pytest

from handtouch.progress import SPEED_PRIOR_S, Heartbeat, RunPlan, loop_eta, with_steps_after


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_run_eta_adds_the_later_phases_to_the_current_one():
    plan = RunPlan({"data": 10.0, "train": 100.0, "eval": 20.0}, untimed=("data",))
    assert plan.remaining("data", 4.0) == pytest.approx(6.0 + 120.0)
    plan.finished("data", 1.0)                  # cached data: untimed, says nothing about speed
    assert plan.speed() == 1.0
    assert plan.remaining("train", 30.0) == pytest.approx(70.0 + 20.0)
    # a loop that reports more left than the plan expects wins (the plan was optimistic)
    assert plan.remaining("train", 30.0, loop_left=200.0) == pytest.approx(200.0 + 20.0)


def test_speed_rescales_the_plan_once_timed_phases_finish():
    plan = RunPlan({"train": 100.0, "eval": 20.0, "report": 10.0})
    plan.finished("train", 250.0)               # 2.5x slower than planned (a loaded machine)
    speed = (250.0 + SPEED_PRIOR_S) / (100.0 + SPEED_PRIOR_S)
    assert plan.speed() == pytest.approx(speed)
    assert plan.remaining("eval", 5.0) == pytest.approx(20.0 * speed - 5.0 + 10.0 * speed)
    tiny = RunPlan({"split": 1.0, "train": 100.0})
    tiny.finished("split", 3.0)                 # a 1 s phase taking 3 s barely moves the ETA
    assert tiny.speed() == pytest.approx(33.0 / 31.0)
    # a phase running past its plan is evidence too, before it ends: 200 s into a 100 s phase
    assert tiny.speed("train", 50.0) == tiny.speed()
    assert tiny.speed("train", 200.0) == pytest.approx(233.0 / 131.0)


def test_a_loop_eta_counts_the_later_loops_of_its_phase():
    report = {"what": "stage 1", "step": 50, "steps": 100, "steps_per_s": 10.0, "samples_per_s": 80.0}
    assert loop_eta(report) == 5.0
    got = []
    with_steps_after(got.append, 300)(report)  # stages 2 and 3 still to come
    assert loop_eta(got[0]) == 35.0
    assert with_steps_after(None, 300) is None and loop_eta(None) is None


def test_heartbeat_line_gives_the_run_eta():
    clock = Clock()
    plan = RunPlan({"rgb_pretrain": 40.0, "train_vit": 80.0, "report": 5.0}, untimed=("rgb_pretrain",))
    beat = Heartbeat(every_s=60, emit=lambda line: None, plan=plan, clock=clock)
    beat.phase("rgb_pretrain")
    clock.t = 10.0
    beat.report(with_steps_after(lambda s: s, 1200)({"what": "aligned probe", "step": 100, "steps": 600,
                                                      "steps_per_s": 20.0, "samples_per_s": 640.0}))
    line = beat.line()
    # this probe's 25 s (the loop's own ETA) and two more probes' 60 s, then 85 s of later phases
    assert line.startswith("smoke: rgb_pretrain 10 s: aligned probe step 100/600") and "ETA 25 s" in line
    assert line.endswith("run 10 s in, ETA ~170 s")
    clock.t = 100.0
    beat.phase("train_vit")                      # the probes are done: their time is not the run's speed
    clock.t = 110.0
    assert beat.line().endswith("run 110 s in, ETA ~75 s")


def test_free_cores_leaves_out_the_cores_other_processes_keep_busy():
    """The smoke's evaluation threads (handtouch.distributed.free_cores): two spinning processes take
    two cores (at least one is always left); this process's own threads do not count against it."""
    import os
    import subprocess
    import sys

    from handtouch.distributed import free_cores

    cores = len(os.sched_getaffinity(0))
    assert 1 <= free_cores() <= cores
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        import time
        time.sleep(0.3)                       # both spinning before the measure
        assert free_cores(sample_s=0.5) <= max(1, cores - 1)
    finally:
        for p in spin:
            p.kill()
            p.wait()
