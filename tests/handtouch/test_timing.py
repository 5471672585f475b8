"""The held-out gate on synthetic predictions: contact-timing AUROC, its mis-paired control, the
F-RMSE report (handtouch/bench/timing.py, handtouch/contact_gate.py `gate`)."""

import itertools

import numpy as np
import pytest
import torch

from handtouch.bench.timing import (
    AUROC_FLOOR,
    MISPAIRED_GAP,
    FrameTable,
    auroc,
    contact_mass,
    contact_streams,
    has_contact,
    lag_check,
    lag_curve,
    position_bin,
    position_clock,
    rmse_report,
    timing_checks,
    timing_scores,
)
from handtouch.contact_gate import gate, phase_partners


def _brute_auroc(scores, labels) -> float:
    pos = [s for s, y in zip(scores, labels) if y]
    neg = [s for s, y in zip(scores, labels) if not y]
    wins = sum(1.0 if p > n else 0.5 if p == n else 0.0 for p, n in itertools.product(pos, neg))
    return wins / (len(pos) * len(neg))


def test_auroc_is_the_mann_whitney_probability_with_ties_counting_half():
    rng = np.random.default_rng(0)
    for _ in range(20):
        scores = rng.integers(0, 5, 30).astype(float)      # many ties
        labels = rng.random(30) < 0.4
        assert auroc(scores, labels) == pytest.approx(_brute_auroc(scores, labels))
    assert auroc([0.1, 0.2, 0.9, 0.8], [False, False, True, True]) == 1.0
    assert auroc([0.9, 0.8, 0.1, 0.2], [False, False, True, True]) == 0.0
    assert auroc([0.5] * 4, [False, True, False, True]) == 0.5     # a constant score says nothing
    assert auroc([0.1, 0.2], [True, True]) is None                  # one class: undefined, never faked
    with pytest.raises(ValueError, match="non-finite"):
        auroc([0.1, float("nan")], [True, False])


def test_contact_label_and_mass_read_only_covered_pixels():
    tactile = torch.zeros(3, 1, 8, 8)
    coverage = torch.zeros(3, 1, 8, 8)
    coverage[:, :, :4] = 1
    tactile[0, 0, 0, 0] = 0.5          # covered contact
    tactile[1, 0, 7, 7] = 0.9          # outside the glove: no contact
    tactile[2, 0, 0, 0] = 0.01         # below the contact level (noise)
    assert has_contact(tactile, coverage).tolist() == [True, False, False]
    pred = torch.full((3, 1, 8, 8), 2.0)                     # clamped to 1 on the 32 covered pixels
    pred[:, :, 4:] = 5.0                                     # uncovered: ignored
    assert contact_mass(pred, coverage).tolist() == [1.0, 1.0, 1.0]
    assert contact_mass(-pred, coverage).tolist() == [0.0, 0.0, 0.0]


def _table(rng, episodes=6, frames=40, *, reads_frame: bool, task="held", idle_hand=True) -> FrameTable:
    """Streams of `frames` frames, contact in the middle; the predicted contact mass follows the
    label when `reads_frame`, else it is noise around a per-hand level (a model that paints the
    same touch whatever it sees). The mis-paired mass is the same model on another episode's frame."""
    ep, hand, label = [], [], []
    for e in range(episodes):
        start = int(rng.integers(5, 15))
        for h in ((0, 1) if idle_hand else (1,)):
            touched = np.zeros(frames, bool)
            if h == 1:
                touched[start:start + 15] = True
            ep += [e] * frames
            hand += [h] * frames
            label += touched.tolist()
    ep, hand, label = np.array(ep), np.array(hand), np.array(label)
    n = len(label)
    level = 0.2 * hand + 0.05                     # the hand token alone: right hands paint more
    aligned = level + (0.3 * label if reads_frame else 0.0) + rng.normal(0, 0.05, n)
    mispaired = level + 0.3 * rng.permutation(label) * reads_frame + rng.normal(0, 0.05, n)
    count = np.full(n, 100.0)
    truth = 0.4 * label
    sq = {"zeros": count * truth ** 2,
          "aligned": count * (truth - np.clip(aligned - level, 0, 1)) ** 2,
          "mispaired": count * (truth - np.clip(mispaired - level, 0, 1)) ** 2}
    return FrameTable(ep, hand, np.array([task] * n), label, count,
                      {"aligned": aligned, "mispaired": mispaired}, sq)


def test_a_model_that_reads_the_frame_passes_the_gate():
    scores = timing_scores(_table(np.random.default_rng(1), reads_frame=True))
    assert scores["auroc"] > 0.95 and scores["mispaired_auroc"] < 0.65
    assert scores["streams"] == 6 and scores["idle_streams"] == 6     # idle left hands left out
    checks = timing_checks(scores, "held-out (ood) held")
    assert all(c["ok"] and c["required"] for c in checks)
    assert "AUROC" in checks[0]["check"] and "held-out (ood)" in checks[0]["check"]
    assert "mis-paired" in checks[1]["check"]


def test_a_model_blind_to_the_frame_fails_the_gate_though_idle_hands_would_lift_it():
    table = _table(np.random.default_rng(2), reads_frame=False)
    scores = timing_scores(table)
    assert scores["auroc"] < AUROC_FLOOR
    assert not any(c["ok"] for c in timing_checks(scores, "held-out (ood) held"))
    # counting the idle hands, hand identity alone would look like timing: the restriction matters
    assert auroc(table.mass["aligned"], table.label) > 0.8


def test_a_model_that_keeps_its_timing_on_mis_paired_rgb_fails_the_gap():
    table = _table(np.random.default_rng(3), reads_frame=True)
    table.mass["mispaired"] = table.mass["aligned"] + 0.01     # e.g. timing read from somewhere but the frame
    checks = timing_checks(timing_scores(table), "test")
    assert checks[0]["ok"] and not checks[1]["ok"]
    assert checks[1]["limit"] == pytest.approx(timing_scores(table)["mispaired_auroc"] + MISPAIRED_GAP)


def test_no_stream_with_contact_fails_the_gate_instead_of_passing():
    table = _table(np.random.default_rng(4), reads_frame=True)
    empty = table.select(~table.label)
    scores = timing_scores(empty)
    assert scores["auroc"] is None and scores["streams"] == 0
    assert not any(c["ok"] for c in timing_checks(scores, "test"))


def test_contact_streams_are_the_episode_hands_with_a_contact_frame():
    keep = contact_streams([0, 0, 0, 0, 1, 1], [0, 0, 1, 1, 1, 1], [False, False, False, True, False, False])
    assert keep.tolist() == [False, False, True, True, False, False]


def test_rmse_report_measures_three_ways_against_the_better_reference():
    table = _table(np.random.default_rng(5), reads_frame=True)
    rep = rmse_report(table)
    assert set(rep) == {"per frame", "pooled", "contact frames"}
    assert rep["contact frames"]["frames"] == int(table.label.sum())
    for r in rep.values():
        assert r["reference"] == min(r["zeros"], r["mispaired"]) and r["ok"] == (r["aligned"] < r["reference"])
    per = rep["per frame"]
    assert per["zeros"] == pytest.approx(np.sqrt(table.sq_err["zeros"] / table.count).mean())
    assert rep["pooled"]["zeros"] == pytest.approx(np.sqrt(table.sq_err["zeros"].sum() / table.count.sum()))


def test_gate_requires_test_and_the_held_out_task_and_reports_the_stress_task():
    rng = np.random.default_rng(6)
    held = _table(rng, reads_frame=True, task="cup")
    stress = _table(rng, reads_frame=False, task="palm")
    stress.episode = stress.episode + 100
    ood = FrameTable(*(np.concatenate([getattr(held, f), getattr(stress, f)])
                       for f in ("episode", "hand", "task", "label", "count")),
                     {k: np.concatenate([held.mass[k], stress.mass[k]]) for k in held.mass},
                     {k: np.concatenate([held.sq_err[k], stress.sq_err[k]]) for k in held.sq_err})
    checks, report = gate({"test": _table(rng, reads_frame=True, task="seen"), "ood": ood}, "cup", "palm")
    assert set(report) == {"test", "ood", "stress"} and report["ood"]["timing"]["tasks"] == ["cup"]
    assert "phase_matched_auroc" not in report["ood"]["timing"]     # not scored: not checked
    required = [c for c in checks if c["required"]]
    assert len(required) == 4 and all(c["ok"] for c in required)   # tables without frames: no lag check
    stress_checks = [c for c in checks if "stress" in c["check"]]
    assert len(stress_checks) == 2 and not any(c["required"] or c["ok"] for c in stress_checks)
    # the same gate when the held-out task is the blind one: a required check fails
    checks, _ = gate({"test": _table(rng, reads_frame=True), "ood": ood}, "palm", None)
    assert not all(c["ok"] for c in checks if c["required"])


# ---- the phase-matched control, the clock reference and the lag check (issue #45) ----------------

def _clock_world(rng, episodes=8, frames=60, varied=False):
    """(episode, frame, position, label) of right-hand streams; contact in the middle third of every
    episode, or (varied) at a random place of each."""
    ep, fr, label = [], [], []
    for e in range(episodes):
        start = int(rng.integers(-15, frames - 5)) if varied else frames // 3   # varied: may run off an end
        touched = np.zeros(frames, bool)
        touched[max(start, 0):start + 20] = True
        ep += [e] * frames
        fr += list(range(frames))
        label += touched.tolist()
    ep, fr, label = np.array(ep), np.array(fr), np.array(label)
    return ep, fr, (fr + 0.5) / frames, label


def _timing_table(ep, fr, pos, label, mass: dict) -> FrameTable:
    n = len(label)
    sq = {k: np.zeros(n) for k in ("aligned", "mispaired", "zeros")}
    return FrameTable(ep, np.ones(n, np.int64), np.array(["held"] * n), label, np.full(n, 100.0), mass, sq, fr, pos)


def test_a_clock_passes_the_mis_paired_control_but_not_the_phase_matched_one():
    """A 'model' that paints contact by where in its episode the frame is (what video played backwards
    keeps when contact sits mid-episode) beats another episode's frame at a random moment, but not
    another episode's frame at the same moment."""
    rng = np.random.default_rng(7)
    ep, fr, pos, label = _clock_world(rng)
    clock = position_clock(pos, label)
    by_position = clock[position_bin(pos)] + rng.normal(0, 0.01, len(pos))
    partner = phase_partners(ep, np.zeros(len(ep)), pos, seed=0)
    assert (ep[partner] != ep).all() and np.abs(pos[partner] - pos).max() < 1e-9
    random_moment = by_position[rng.permutation(len(pos))]
    table = _timing_table(ep, fr, pos, label, {"aligned": by_position, "mispaired": random_moment,
                                               "phase_matched": by_position[partner]})
    scores = timing_scores(table, clock)
    assert scores["auroc"] > 0.95 and scores["position_auroc"] > 0.95
    checks = {c["check"].split(" >= ")[1].split(" ")[0]: c["ok"] for c in timing_checks(scores, "held")}
    assert checks == {"0.7": True, "mis-paired": True, "phase-matched": False}, checks


def test_where_timing_varies_the_clock_scores_near_chance_and_a_frame_reader_passes_every_control():
    rng = np.random.default_rng(8)
    ep, fr, pos, label = _clock_world(rng, episodes=40, varied=True)
    clock = position_clock(pos, label)
    reads = label + rng.normal(0, 0.2, len(label))
    partner = phase_partners(ep, np.zeros(len(ep)), pos, seed=0)
    table = _timing_table(ep, fr, pos, label, {"aligned": reads, "mispaired": reads[rng.permutation(len(pos))],
                                               "phase_matched": reads[partner]})
    scores = timing_scores(table, clock)
    assert scores["position_auroc"] < 0.65 and all(c["ok"] for c in timing_checks(scores, "held"))


def test_phase_partners_prefer_the_same_task_and_need_another_episode():
    ep = np.array([0, 0, 1, 1, 2, 2])
    task = np.array(["a", "a", "b", "b", "a", "a"])
    pos = np.array([0.1, 0.9, 0.1, 0.9, 0.2, 0.8])
    out = phase_partners(ep, task, pos)
    assert out.tolist() == [4, 5, 2, 3, 0, 1] or out[:2].tolist() == [4, 5]
    assert set(ep[out[:2]]) == {2} and set(ep[out[4:]]) == {0}    # task a pairs within a
    assert set(ep[out[2:4]]) <= {0, 2}                               # task b has no twin: any other
    assert (phase_partners(np.zeros(3, int), np.array(["a"] * 3), np.array([0.1, 0.5, 0.9])) == -1).all()


@pytest.mark.parametrize("lag", [0, 1, 6])
def test_the_lag_curve_finds_the_frames_the_rgb_lags_by(lag):
    """Predictions that follow the label `lag` frames late (what a model shows on video that lags its
    glove by `lag` frames) agree best at shift -lag; the check passes within 2 frames and names the lag."""
    rng = np.random.default_rng(9)
    ep, fr, pos, label = _clock_world(rng, episodes=10, varied=True)
    late = np.zeros(len(label))
    for e in np.unique(ep):
        rows = np.flatnonzero(ep == e)
        late[rows] = np.concatenate([np.zeros(lag), label[rows][:len(rows) - lag]]) if lag else label[rows]
    mass = late + rng.normal(0, 0.05, len(label))
    curve = lag_curve(_timing_table(ep, fr, pos, label, {"aligned": mass, "mispaired": mass}), 30)
    assert curve["best_shift"] == -lag and len(curve["shifts"]) == 61
    check = lag_check(curve, "test", fps=30.0)
    assert check["ok"] == (lag <= 2)
    if lag > 2:
        assert f"the RGB lags the glove by {lag} frames (0.20 s at 30 fps)" in check["check"]


def test_the_lag_curve_of_a_subsampled_table_and_of_none():
    rng = np.random.default_rng(10)
    ep, fr, pos, label = _clock_world(rng, episodes=10, varied=True)
    keep = rng.random(len(ep)) < 0.6                     # the gate scores a subsample of a part
    table = _timing_table(ep, fr, pos, label, {"aligned": label + rng.normal(0, 0.1, len(ep)),
                                               "mispaired": np.zeros(len(ep))}).select(keep)
    assert lag_curve(table, 10)["best_shift"] == 0
    empty = table.select(np.zeros(len(table), bool))
    curve = lag_curve(empty, 5)
    assert curve["best_shift"] is None and not lag_check(curve, "test", 30.0)["ok"]


def test_the_lag_curve_of_a_model_that_does_not_follow_contact_in_time_has_no_peak():
    """Predictions that follow the label pass the peak check and the floor; those of video played backwards
    (the label of the mirrored moment) or of a clock do not pass both; a curve as high 0.5 s away as at its
    best fails the peak check."""
    from handtouch.bench.timing import lag_peak_check

    rng = np.random.default_rng(11)
    ep, fr, pos, label = _clock_world(rng, episodes=30, frames=90, varied=True)
    mirrored = np.zeros(len(label))
    for e in np.unique(ep):
        rows = np.flatnonzero(ep == e)
        mirrored[rows] = label[rows][::-1]
    clock = position_clock(pos, label)[position_bin(pos)]
    follows = label + rng.normal(0, 0.1, len(label))
    for mass, ok in ((follows, True), (mirrored + rng.normal(0, 0.1, len(label)), False), (clock, False)):
        curve = lag_curve(_timing_table(ep, fr, pos, label, {"aligned": mass, "mispaired": mass}), 30, 15)
        passes = lag_peak_check(curve, "test", 30.0)["ok"] and curve["at_zero"] >= AUROC_FLOOR
        assert passes == ok, curve
    flat = lag_curve(_timing_table(ep, fr, pos, label, {"aligned": np.full(len(label), 0.5),
                                                         "mispaired": follows}), 30, 15)
    assert flat["side_auroc"] == flat["best_auroc"] and not lag_peak_check(flat, "test", 30.0)["ok"]


@pytest.mark.parametrize("lag", [0, 6])
def test_the_gate_s_lag_check_pools_test_and_held_out_streams(lag):
    """One required lag check on the test and held-out streams together (the lag is the pipeline's); each
    part's best shift is reported, each part's peak required."""
    rng = np.random.default_rng(12)
    parts = {}
    for name, task, first in (("test", "seen", 0), ("ood", "cup", 100)):
        ep, fr, pos, label = _clock_world(rng, episodes=8, frames=90, varied=True)
        late = np.zeros(len(label))
        for e in np.unique(ep):
            rows = np.flatnonzero(ep == e)
            late[rows] = np.concatenate([np.zeros(lag), label[rows][:len(rows) - lag]]) if lag else label[rows]
        mass = late + rng.normal(0, 0.1, len(label))
        t = _timing_table(ep + first, fr, pos, label, {"aligned": mass, "mispaired": rng.permutation(mass),
                                                       "phase_matched": rng.permutation(mass)})
        t.task = np.array([task] * len(label))
        parts[name] = t
    checks, report = gate(parts, "cup", None)
    pooled = [c for c in checks if c["check"].startswith("lag:") and "test and held-out (ood) cup" in c["check"]]
    assert len(pooled) == 1 and pooled[0]["required"] and pooled[0]["ok"] == (lag == 0)
    assert report["lag"]["curve"]["best_shift"] == -lag
    per_part = [c for c in checks if c["check"].startswith("lag: predicted and measured") and c not in pooled]
    assert len(per_part) == 2 and not any(c["required"] for c in per_part)
    if lag:
        assert "the RGB lags the glove by 6 frames" in pooled[0]["check"]
