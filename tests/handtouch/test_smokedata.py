"""The smoke's data and exit status: the split validator's leak check on its split, the held-out
tasks, the mis-paired control's verdict (handtouch/smokedata.py, handtouch/smokechecks.py)."""

import pytest

from handtouch.smokechecks import verdict
from handtouch.smokedata import OOD_TASK, STRESS_TASK, make_split, split_leak_check
from htdata.curate.split import make_split as write_split
from htdata.synthetic.tasks import TASKS, TWINS
from tests.factories import SPLIT_EPISODES, edit_split, write_synthetic_dataset


@pytest.fixture
def ds(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", SPLIT_EPISODES, seed=1)
    write_split(root, ["pour"], name="smoke")
    return root


def test_a_sound_split_passes_the_leak_check(ds):
    check = split_leak_check(ds)
    assert check["ok"] and check["required"] and check["value"] == 0 and check["ood_task_leaks"] == 0


def test_a_held_out_episode_in_train_fails_the_leak_check(ds):
    edit_split(ds, "smoke", lambda d: (d["parts"]["ood"]["episodes"].remove("ep_a"),
                                       d["parts"]["train"]["episodes"].append("ep_a")))
    check = split_leak_check(ds)
    assert not check["ok"] and check["required"] and check["ood_task_leaks"] == 2   # in train, and not in ood
    assert any("ep_a of OOD task pour is in train" in m for m in check["failures"])


def test_make_split_names_the_missing_held_out_task(ds, capsys):
    with pytest.raises(SystemExit, match="cup_grasp.*older sample corpus"):
        make_split(ds, [OOD_TASK], seed=0)


def test_the_held_out_task_shares_its_touch_with_a_training_task_and_the_stress_task_none():
    twin = TASKS[TWINS[OOD_TASK]]
    held, stress = TASKS[OOD_TASK], TASKS[STRESS_TASK]
    assert (held.contact, held.support, held.closure, held.anchor) == (twin.contact, twin.support, twin.closure,
                                                                        twin.anchor)
    assert held.shape != twin.shape and held.colour != twin.colour            # a new object
    others = [t for name, t in TASKS.items() if name not in (OOD_TASK, STRESS_TASK)]
    assert all(set(t.contact) != set(stress.contact) for t in others)


def test_exit_status_of_the_smoke_and_of_the_mis_paired_control():
    gate = {"check": "contact-timing AUROC (held-out (ood) cup_grasp, streams with contact) >= 0.7",
            "ok": False, "required": True}
    other = {"check": "RGB-to-tactile F-RMSE (test) < all zeros", "ok": False, "required": True}
    reported = {"check": "contact-timing AUROC (held-out stress test palm_push) >= 0.7", "ok": False,
                "required": False}
    assert verdict([{**gate, "ok": True}, reported]) == 0            # reported checks never fail a run
    assert verdict([gate, reported]) == 1
    assert verdict([gate, other], control=True) == 0                 # the control: the gate caught it
    assert verdict([{**gate, "ok": True}, other], control=True) == 1   # the gate passed on broken data


def test_the_control_builds_its_own_data_and_the_plan_knows_what_is_cached(tmp_path, capsys):
    import json

    from handtouch.smoke import PHASE_SECONDS, parse_args, run_plan

    with pytest.raises(SystemExit):
        parse_args(["--out", str(tmp_path), "--mispaired-rgb", "--dataset", str(tmp_path / "ds")])
    assert "--broken builds its own corpus" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parse_args(["--out", str(tmp_path), "--mispaired-rgb", "--broken", "lagged"])
    assert parse_args(["--out", str(tmp_path), "--broken", "lagged"]).lag_frames == 6
    args = parse_args(["--out", str(tmp_path), "--mispaired-rgb"])
    assert args.broken == "mispaired"
    assert args.raw == tmp_path / "raw" and args.dataset == tmp_path / "dataset"
    plan = run_plan(args)                                   # nothing there yet: the defaults
    assert plan.expected["data_sample"] == PHASE_SECONDS["data_sample"]
    assert plan.expected["eval_handtouch-vit"] == PHASE_SECONDS["eval"] and "train_cnn" not in plan.expected
    assert "train_cnn" in run_plan(parse_args(["--out", str(tmp_path), "--encoders", "vit,cnn"])).expected
    write_synthetic_dataset(args.dataset, SPLIT_EPISODES, seed=1)
    (tmp_path / "results.json").write_text(json.dumps({"meta": {"seconds": {"train_vit": 300.0}}}))
    plan = run_plan(args)                                   # the last run's seconds; the dataset is there
    assert plan.expected["train_vit"] == 300.0 and plan.expected["data_ingest"] == 0.0


def test_each_broken_control_passes_only_when_its_own_check_catches_it():
    from handtouch.bench.timing import lag_check

    gate = {"check": "contact-timing AUROC (held-out (ood) cup_grasp) >= phase-matched RGB's + 0.15", "ok": False,
            "required": True}
    curve = {"best_shift": -6, "best_auroc": 0.9, "shifts": [], "auroc": []}
    lag = lag_check(curve, "held-out (ood) cup_grasp", fps=30.0)
    assert not lag["ok"] and "the RGB lags the glove by 6 frames (0.20 s at 30 fps)" in lag["check"]
    assert verdict([gate], control="reversed") == 0 and verdict([{**gate, "ok": True}], control="reversed") == 1
    assert verdict([lag], control="lagged") == 0
    assert verdict([gate], control="lagged") == 1          # the lag must be caught by the lag check, named
    ahead = lag_check({**curve, "best_shift": 6}, "test", fps=30.0)
    assert verdict([ahead], control="lagged") == 1         # a lag the other way is not the one built
