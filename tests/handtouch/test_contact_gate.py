"""The held-out gate on a dataset (handtouch.contact_gate.score_part): a model that reads the frame
passes, the same model on a dataset whose RGB says nothing about the touch fails."""

import zlib

import numpy as np
import torch

from handtouch.contact_gate import GateConfig, gate, score_part
from htdata.format.canvas import CANVAS
from tests import factories
from tests.factories import commit_split, episode_table, write_synthetic_dataset

EPISODES = episode_table(*[(f"s{i}", "seen", "lab", "R", 16) for i in range(4)],
                         *[(f"h{i}", "held", "lab", "R", 16) for i in range(4)])


def _level(seed: int, episode_id: str, frame: int) -> float:
    """Pressure of a frame: none in 2 of 4 frames, drawn afresh per frame."""
    rng = np.random.default_rng([seed, zlib.crc32(episode_id.encode()), frame, 7])
    return float(rng.choice([0.0, 0.0, 0.5, 1.0]))


def _tactile(seed, episode_id, frame, hand, coverage):
    return (_level(seed, episode_id, frame) * 0.8 * (coverage > 0)).astype(np.float32)


class BrightnessModel:
    """Predicts touch from the frame's brightness (what a model that reads the frame does)."""

    name = "brightness"

    def rgb_to_tactile(self, rgb, coverage, hand):
        level = (rgb.float().mean((1, 2, 3)) - 40) / 200
        return level[:, None, None, None].clamp(0, 1) * coverage


def _dataset(root, monkeypatch, aligned: bool):
    monkeypatch.setattr(factories, "synthetic_tactile", _tactile)

    def rgb(seed, episode_id, frame):
        level = _level(seed, episode_id, frame) if aligned else _level(seed + 99, episode_id, frame)
        return np.full((CANVAS, CANVAS, 3), int(40 + 200 * level), np.uint8)
    monkeypatch.setattr(factories, "synthetic_rgb", rgb)
    write_synthetic_dataset(root, EPISODES, seed=1)
    commit_split(root, "s", {"train": ["s0", "s1"], "test": ["s2", "s3"], "ood": [f"h{i}" for i in range(4)]})
    return root


def _gate(root):
    with torch.inference_mode():
        tables = {p: score_part(BrightnessModel(), root, "s", p, GateConfig(max_frames=64)) for p in ("test", "ood")}
    return tables, gate(tables, "held", None)


def test_a_model_that_reads_aligned_rgb_passes_and_the_table_is_the_parts(tmp_path, monkeypatch):
    tables, (checks, report) = _gate(_dataset(tmp_path / "ok", monkeypatch, aligned=True))
    assert len(tables["test"]) == 32 and len(tables["ood"]) == 64 and set(tables["ood"].task) == {"held"}
    assert 0 < tables["ood"].label.sum() < 64
    assert all(c["ok"] for c in checks), checks
    assert report["ood"]["timing"]["auroc"] == 1.0 and report["ood"]["timing"]["mispaired_auroc"] < 0.8
    assert report["ood"]["rmse"]["contact frames"]["ok"]


def test_the_same_model_fails_where_the_stored_rgb_says_nothing_about_the_touch(tmp_path, monkeypatch):
    _, (checks, report) = _gate(_dataset(tmp_path / "broken", monkeypatch, aligned=False))
    held = [c for c in checks if "held-out (ood) held" in c["check"]]
    assert len(held) == 6 and not all(c["ok"] for c in held), report["ood"]["timing"]   # 3 AUROC, 2 lag, pooled lag
