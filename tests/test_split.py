"""htdata split: determinism, stability, stratification, leakage, errors."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from htdata.curate import split as sp
from htdata.cli import main as cli_main
from htdata.resources import validate_json


def _episodes(spec: dict[str, int], prefix: str = "ep", frames: int = 10, start: int = 0) -> list[dict]:
    """{task: n} -> episode records with ids unique across tasks."""
    out = []
    for task, n in spec.items():
        for i in range(start, start + n):
            out.append({"episode_id": f"{prefix}_{task}_{i:04d}", "task": task,
                        "scene": f"scene{i % 3}", "num_frames": frames + i % 5})
    return out


def _write_dataset(root: Path, episodes: list[dict]) -> Path:
    """Only what split reads: dataset.json and episodes.jsonl."""
    root.mkdir(parents=True, exist_ok=True)
    tasks = sorted({e["task"] for e in episodes})
    (root / "dataset.json").write_text(json.dumps(
        {"format": "htdata", "format_version": 1, "tasks": tasks, "episodes_file": "episodes.jsonl"}))
    (root / "episodes.jsonl").write_text("".join(json.dumps(e) + "\n" for e in episodes))
    return root


def _parts(doc: dict) -> dict[str, str]:
    return {eid: part for part in sp.PARTS for eid in doc["parts"][part]["episodes"]}


def _config(**kw) -> sp.SplitConfig:
    kw.setdefault("ood_tasks", ["pour"])
    return sp.SplitConfig(**kw)


def test_episode_uniform_is_seeded_and_in_unit_interval():
    us = [sp.episode_uniform(0, f"e{i}") for i in range(2000)]
    assert all(0.0 <= u < 1.0 for u in us)
    assert sp.episode_uniform(0, "e1") == sp.episode_uniform(0, "e1")
    assert sp.episode_uniform(0, "e1") != sp.episode_uniform(1, "e1")
    # roughly uniform: each decile holds 10% +- 3%
    counts = [sum(int(u * 10) == d for u in us) for d in range(10)]
    assert all(140 <= c <= 260 for c in counts), counts


def test_split_is_deterministic_and_seed_dependent():
    eps = _episodes({"pour": 5, "grasp": 60, "wipe": 60})
    a = sp.build_split(eps, _config(seed=3), "0" * 64)
    b = sp.build_split(list(reversed(eps)), _config(seed=3), "0" * 64)
    c = sp.build_split(eps, _config(seed=4), "0" * 64)
    assert a["parts"] == b["parts"]
    assert _parts(a) != _parts(c)


def test_ood_tasks_go_whole_to_ood_and_parts_are_disjoint_and_complete():
    eps = _episodes({"pour": 7, "grasp": 40, "wipe": 30, "open": 25})
    doc = sp.build_split(eps, _config(ood_tasks=["pour", "open"]), "0" * 64)
    parts = doc["parts"]
    ood_ids = {e["episode_id"] for e in eps if e["task"] in ("pour", "open")}
    assert set(parts["ood"]["episodes"]) == ood_ids
    all_ids = [eid for p in sp.PARTS for eid in parts[p]["episodes"]]
    assert len(all_ids) == len(set(all_ids)) == len(eps)
    task_of = {e["episode_id"]: e["task"] for e in eps}
    assert not {task_of[e] for e in parts["train"]["episodes"] + parts["test"]["episodes"]} & {"pour", "open"}
    frames = {e["episode_id"]: e["num_frames"] for e in eps}
    for p in sp.PARTS:
        assert parts[p]["frames"] == sum(frames[e] for e in parts[p]["episodes"])
    assert doc["tasks"]["pour"]["ood"]["episodes"] == 7
    assert doc["tasks"]["grasp"]["ood"]["episodes"] == 0


def test_stratified_ratio_per_task_and_overall():
    eps = _episodes({"pour": 10, "grasp": 400, "wipe": 400, "lift": 400})
    doc = sp.build_split(eps, _config(test_ratio=0.2, seed=7), "0" * 64)
    for task in ("grasp", "wipe", "lift"):
        t = doc["tasks"][task]
        frac = t["test"]["episodes"] / (t["test"]["episodes"] + t["train"]["episodes"])
        assert 0.14 <= frac <= 0.26, (task, frac)  # binomial(400, 0.2): sd 0.02
    assert abs(doc["ratios"]["test_of_in_distribution"]["episodes"] - 0.2) < 0.04
    assert doc["ratios"]["ood_of_all"]["episodes"] == pytest.approx(10 / 1210)


def test_adding_episodes_never_moves_threshold_decided_episodes():
    base = _episodes({"pour": 4, "grasp": 30, "wipe": 3, "lift": 2})
    more = base + _episodes({"grasp": 50, "wipe": 20, "lift": 10, "pour": 3}, start=1000)
    for seed in range(6):
        before = sp.build_split(base, _config(seed=seed, test_ratio=0.15), "0" * 64)
        after = sp.build_split(more, _config(seed=seed, test_ratio=0.15), "0" * 64)
        corrected = {c["episode_id"] for c in before["corrections"] + after["corrections"]}
        pb, pa = _parts(before), _parts(after)
        for eid, part in pb.items():
            if eid not in corrected:
                assert pa[eid] == part, (seed, eid)
        # and the threshold rule itself is what decided the uncorrected ones
        for eid, part in pa.items():
            if eid not in corrected and part != "ood":
                assert (part == "test") == (sp.episode_uniform(seed, eid) < 0.15)


def test_every_test_task_keeps_train_and_test_episodes():
    # tiny tasks: the pure threshold would often leave test (or train) empty
    eps = _episodes({"pour": 2, **{f"t{i}": 2 + i % 3 for i in range(40)}})
    doc = sp.build_split(eps, _config(test_ratio=0.1, seed=11), "0" * 64)
    for task, counts in doc["tasks"].items():
        if task == "pour":
            continue
        assert counts["train"]["episodes"] >= 1 and counts["test"]["episodes"] >= 1, task
    assert doc["corrections"], "with 40 tiny tasks at ratio 0.1 corrections must happen"
    for c in doc["corrections"]:
        assert _parts(doc)[c["episode_id"]] == c["part"]


def test_all_below_threshold_moves_largest_u_to_train():
    eps = _episodes({"pour": 1, "grasp": 3})
    doc = sp.build_split(eps, _config(test_ratio=0.999), "0" * 64)
    grasp = sorted((sp.episode_uniform(0, e["episode_id"]), e["episode_id"])
                   for e in eps if e["task"] == "grasp")
    assert doc["parts"]["train"]["episodes"] == [grasp[-1][1]]
    assert doc["corrections"][0]["part"] == "train"


def test_single_episode_task_goes_to_train_with_warning():
    eps = _episodes({"pour": 2, "grasp": 20}) + [
        {"episode_id": "lonely", "task": "solo", "scene": "s", "num_frames": 3}]
    for seed in range(20):  # whatever its hash, it lands in train
        doc = sp.build_split(eps, _config(seed=seed, test_ratio=0.5), "0" * 64)
        assert "lonely" in doc["parts"]["train"]["episodes"]
        assert any("'solo' has a single episode (lonely)" in w for w in doc["warnings"])


def test_unknown_task_lists_known_and_suggests_near_match():
    eps = _episodes({"pour_water": 3, "grasp": 5})
    with pytest.raises(sp.SplitError) as exc:
        sp.build_split(eps, _config(ood_tasks=["pour_watr"]), "0" * 64)
    msg = str(exc.value)
    assert "unknown task 'pour_watr'" in msg
    assert "did you mean 'pour_water'" in msg
    assert "known tasks: grasp, pour_water" in msg


def test_ood_task_covering_every_task_is_refused():
    eps = _episodes({"pour": 3})
    with pytest.raises(sp.SplitError, match="covers every task"):
        sp.build_split(eps, _config(ood_tasks=["pour"]), "0" * 64)


@pytest.mark.parametrize("kw, match", [
    ({"ood_tasks": []}, "at least one --ood-task"),
    ({"test_ratio": 0.0}, r"--test-ratio must be in \(0, 1\)"),
    ({"test_ratio": 1.0}, r"--test-ratio must be in \(0, 1\)"),
    ({"test_ratio": float("nan")}, r"--test-ratio must be in \(0, 1\)"),
    ({"name": "a/b"}, "must match"),
    ({"ood_tasks": ["pour", "pour"]}, "given twice"),
])
def test_config_validate_errors(kw, match):
    with pytest.raises(sp.SplitError, match=match):
        _config(**kw).validate()


def test_duplicate_episode_id_is_refused():
    eps = _episodes({"pour": 2, "grasp": 3})
    eps.append(dict(eps[-1]))
    with pytest.raises(sp.SplitError, match="appears twice"):
        sp.build_split(eps, _config(), "0" * 64)


def test_make_split_writes_valid_file_with_manifest_hash(tmp_path):
    eps = _episodes({"pour": 3, "grasp": 12, "wipe": 9})
    ds = _write_dataset(tmp_path / "ds", eps)
    doc = sp.make_split(ds, ["pour"], test_ratio=0.25, seed=1, name="main")
    path = ds / "splits" / "main.json"
    on_disk = json.loads(path.read_text())
    validate_json(on_disk, "split")
    assert on_disk == doc
    assert on_disk["manifest_sha256"] == hashlib.sha256((ds / "dataset.json").read_bytes()).hexdigest()
    assert on_disk["params"] == {"ood_tasks": ["pour"], "test_ratio": 0.25, "seed": 1}
    assert not [p for p in (ds / "splits").iterdir() if p.name != "main.json"]  # no temp left


def test_existing_split_name_is_refused_unless_force(tmp_path):
    ds = _write_dataset(tmp_path / "ds", _episodes({"pour": 3, "grasp": 12}))
    sp.make_split(ds, ["pour"], name="s1")
    with pytest.raises(sp.SplitError, match="already exists.*--force"):
        sp.make_split(ds, ["pour"], name="s1", seed=5)
    doc = sp.make_split(ds, ["pour"], name="s1", seed=5, force=True)
    assert json.loads((ds / "splits" / "s1.json").read_text())["params"]["seed"] == 5 == doc["params"]["seed"]


def test_default_name_is_derived_from_params(tmp_path):
    ds = _write_dataset(tmp_path / "ds", _episodes({"pour": 3, "grasp": 12}))
    doc = sp.make_split(ds, ["pour"], seed=2)
    assert doc["name"] == "ood-pour-seed2"
    assert (ds / "splits" / "ood-pour-seed2.json").is_file()


def test_cli_split_and_list_tasks(tmp_path, capsys):
    ds = _write_dataset(tmp_path / "ds", _episodes({"pour": 3, "grasp": 12}))
    assert cli_main(["split", str(ds), "--list-tasks"]) == 0
    out = capsys.readouterr().out
    assert "grasp" in out and "(all scenes)" in out and "2 tasks, 15 episodes" in out
    # grasp scene0 holds episodes 0,3,6,9 -> 4 episodes with 10+0,13,11,14 frames
    line = next(l for l in out.splitlines() if l.startswith("grasp") and "scene0" in l)
    assert line.split()[-2:] == ["4", str(10 + 13 + 11 + 14)]

    assert cli_main(["split", str(ds), "--ood-task", "pour", "--name", "x", "--test-ratio", "0.3"]) == 0
    assert (ds / "splits" / "x.json").is_file()
    assert cli_main(["split", str(ds), "--ood-task", "pour", "--name", "x"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert cli_main(["split", str(ds), "--ood-task", "grasps", "--name", "y"]) == 2
    assert "did you mean 'grasp'" in capsys.readouterr().err


def test_missing_dataset_is_a_clear_error(tmp_path):
    with pytest.raises(sp.SplitError, match="no dataset.json"):
        sp.make_split(tmp_path / "nope", ["pour"])
