"""handtouch.task_transfer: leave-one-task-out RGB probes, on synthetic datasets whose RGB
does or does not say where a new task touches."""

import json
import zlib

import numpy as np
import pytest

from handtouch.rgb_pretrain import RGBPretrainConfig
from handtouch.task_transfer import item_parts, main, markdown, transfer_table
from htdata.format.canvas import CANVAS
from htdata.store.manifest import load_episodes
from tests import factories
from tests.factories import episode_table, write_synthetic_dataset

# threads=1: two test workers share the 2 cores; 2 threads each would oversubscribe them
TINY = RGBPretrainConfig(steps=150, batch_size=16, lr=3e-3, warmup_steps=5, shift_pixels=1, brightness=0.0,
                         threads=1, arch={"size": 16, "width": 16, "channels": 4, "grid": 14, "hidden": 32})
TASKS = ("a", "b", "c")
EPISODES = episode_table(*[(f"{t}-{i}", t, "lab", "R", 12) for t in TASKS for i in range(4)])
# where each task touches, as a canvas position (row, col) of a blob
PLACES = {"a": (56, 56), "b": (112, 112), "c": (168, 168)}


def _level(seed: int, episode_id: str, frame: int) -> float:
    return float(np.random.default_rng([seed, zlib.crc32(episode_id.encode()), frame, 7]).choice(
        [0.0, 0.25, 0.5, 0.75, 1.0]))


def _blob(centre) -> np.ndarray:
    yy, xx = np.mgrid[0:CANVAS, 0:CANVAS].astype(np.float32)
    return np.exp(-((yy - centre[0]) ** 2 + (xx - centre[1]) ** 2) / (2 * 30.0 ** 2))


def _dataset(root, monkeypatch, place_by_task: bool):
    """RGB brightness shows how hard the hand presses, never where. place_by_task: each task
    presses its own place, so a held-out task's place is one no probe saw; else all press the centre."""
    def tactile(seed, episode_id, frame, hand, coverage):
        centre = PLACES[episode_id.split("-")[0]] if place_by_task else PLACES["b"]
        return (_level(seed, episode_id, frame) * _blob(centre) * (coverage > 0)).astype(np.float32)

    def rgb(seed, episode_id, frame):
        return np.full((CANVAS, CANVAS, 3), int(40 + 200 * _level(seed, episode_id, frame)), np.uint8)

    monkeypatch.setattr(factories, "synthetic_tactile", tactile)
    monkeypatch.setattr(factories, "synthetic_rgb", rgb)
    return write_synthetic_dataset(root, EPISODES, seed=1, fps=4.0)


def test_item_parts_hold_the_task_out_whole_and_split_the_rest_by_episode():
    episodes = [{"episode_id": f"{t}-{i}", "task": t} for t in TASKS for i in range(10)]
    item_episode = np.repeat(np.arange(len(episodes)), 3)
    parts = item_parts(episodes, item_episode, "b", 0.1, 0)
    task = np.array([episodes[e]["task"] for e in item_episode])
    assert (parts[task == "b"] == "ood").all() and "ood" not in parts[task != "b"]
    for t in ("a", "c"):
        assert {"train", "test"} <= set(parts[task == t])          # each seen task has a test episode
    for e in range(len(episodes)):                                # an episode's items share one part
        assert len(set(parts[item_episode == e])) == 1


def test_rgb_that_shows_the_touch_transfers_to_every_held_out_task(tmp_path, monkeypatch):
    root = _dataset(tmp_path / "ds", monkeypatch, place_by_task=False)
    doc = transfer_table(root, TINY, probe_dir=tmp_path / "probes", progress=lambda s: None)
    assert list(doc["tasks"]) == list(TASKS)
    for task, row in doc["tasks"].items():
        assert row["held"]["items"] == 4 * 12 and row["train_items"] < 8 * 12
        assert row["held"]["ratio"] < 0.5, (task, row)
        assert (tmp_path / "probes" / f"{task}.pt").is_file()


def test_a_place_no_training_task_touches_does_not_transfer(tmp_path, monkeypatch):
    root = _dataset(tmp_path / "ds", monkeypatch, place_by_task=True)
    doc = transfer_table(root, TINY, tasks=["a", "c"], probe_dir=tmp_path / "probes", progress=lambda s: None)
    for task, row in doc["tasks"].items():
        # RGB still says when: the probe beats zeros on the tasks it saw, never on the new place
        assert row["seen"]["ratio"] < 0.7 and row["held"]["ratio"] >= 1.0, (task, row)


def test_cli_writes_the_table_and_leaves_the_dataset_alone(tmp_path, monkeypatch, capsys):
    root = _dataset(tmp_path / "ds", monkeypatch, place_by_task=False)
    before = sorted(p.relative_to(root) for p in root.rglob("*"))
    assert main(["--dataset", str(root), "--out", str(tmp_path / "out"), "--tasks", "a", "--max-items", "64"]) == 0
    doc = json.loads((tmp_path / "out" / "task_transfer.json").read_text())
    assert list(doc["tasks"]) == ["a"] and doc["items"] == 64
    assert "| a |" in (tmp_path / "out" / "task_transfer.md").read_text() and "| a |" in capsys.readouterr().out
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before     # no split written
    assert len(load_episodes(root)) == len(EPISODES)
    with pytest.raises(SystemExit, match="no task"):
        main(["--dataset", str(root), "--out", str(tmp_path / "out"), "--tasks", "zzz"])


def test_probe_fields_come_from_the_command_line(tmp_path, monkeypatch):
    root = _dataset(tmp_path / "ds", monkeypatch, place_by_task=False)
    out = tmp_path / "out"
    assert main(["--dataset", str(root), "--out", str(out), "--tasks", "b", "--max-items", "64",
                 "--probe", "steps=3", "--probe", 'loss="frame_rmse"']) == 0
    cfg = json.loads((out / "task_transfer.json").read_text())["config"]
    assert cfg["steps"] == 3 and cfg["loss"] == "frame_rmse" and cfg["max_items"] == 64
    assert 'with `steps=3`, `loss="frame_rmse"` trained' in (out / "task_transfer.md").read_text()
    for bad in ("seed=3", "nonsense=1", "steps"):
        with pytest.raises(SystemExit):
            main(["--dataset", str(root), "--out", str(out), "--probe", bad])


def test_controls_on_each_split(tmp_path, monkeypatch):
    """Pressure drawn afresh each frame: a frame 1 s away, or of another episode, says nothing,
    so both controls score worse than the aligned probe on every split."""
    root = _dataset(tmp_path / "ds", monkeypatch, place_by_task=False)
    doc = transfer_table(root, TINY, tasks=["a", "b"], probe_dir=tmp_path / "probes", progress=lambda s: None,
                         controls=True)
    for task, row in doc["tasks"].items():
        assert set(row["controls"]) == {"shifted", "shuffled"}
        for pairing, got in row["controls"].items():
            assert got["ratio"] > row["seen"]["ratio"] + 0.3, (task, pairing, row)
            assert (tmp_path / "probes" / f"{task}-{pairing}.pt").is_file()
    md = markdown(doc)
    assert "## Misalignment controls on each split" in md and md.count("| a |") == 2
