"""The pretrained frozen RGB encoder and the misalignment control (handtouch.rgb_pretrain)."""

import dataclasses
import zlib

import numpy as np
import pytest
import torch

from handtouch.bench.items import EvalConfig, load_part, prepare
from handtouch.distributed import torch_threads
from handtouch.probeitems import load_items
from handtouch.rgb_encoder import TactileGridRGB, load_rgb_encoder
from handtouch.rgb_pretrain import (
    CONTROL_MARGIN,
    MODEL_MARGIN,
    VERSION_RECORD_FIELDS,
    RGBPretrainConfig,
    cache_key,
    content_record,
    control_checks,
    control_scores,
    ensure_probes,
    episode_fps,
    model_control_checks,
    paired_rgb2tactile,
    partners,
    probes_cached,
    save_probe,
)
from htdata.curate.edit import remove_episodes
from htdata.format.canvas import CANVAS
from htdata.read.metadata import DatasetMetadata
from htdata.store.snapshot import commit_parts, open_snapshot
from htdata.store.splitfiles import split_path
from tests import factories
from tests.factories import commit_split, episode_table, write_synthetic_dataset

FPS = 4.0          # 1 s = 4 frames: short episodes can be shifted by a second
# threads=1: two test workers share the 2 cores; 2 threads each would oversubscribe them
TINY = RGBPretrainConfig(steps=150, batch_size=16, lr=3e-3, warmup_steps=5, shift_pixels=1, brightness=0.0,
                         threads=1, arch={"size": 16, "width": 16, "channels": 4, "grid": 14, "hidden": 32})
EPISODES = episode_table(*[(f"ep{i}", "grab", "lab", "R", 12) for i in range(10)])


def _level(seed: int, episode_id: str, frame: int) -> float:
    """How hard the hand presses at a frame: random per frame, so a 1 s shift carries nothing."""
    # salt 7: factories' streams use salts 0-3 (and numpy seeds [a, b, c] like [a, b, c, 0])
    return float(np.random.default_rng([seed, zlib.crc32(episode_id.encode()), frame, 7]).choice(
        [0.0, 0.25, 0.5, 0.75, 1.0]))


def _tactile(seed, episode_id, frame, hand, coverage):
    yy, xx = np.mgrid[0:CANVAS, 0:CANVAS].astype(np.float32)
    blob = np.exp(-((yy - 112) ** 2 + (xx - 112) ** 2) / (2 * 40.0 ** 2))
    return (_level(seed, episode_id, frame) * blob * (coverage > 0)).astype(np.float32)


def _dataset(root, monkeypatch, rgb_shift: int | None):
    """RGB brightness shows the pressure of frame + rgb_shift (None: RGB unrelated to touch)."""
    monkeypatch.setattr(factories, "synthetic_tactile", _tactile)
    if rgb_shift is not None:
        def rgb(seed, episode_id, frame):
            return np.full((CANVAS, CANVAS, 3), int(40 + 200 * _level(seed, episode_id, frame + rgb_shift)), np.uint8)
        monkeypatch.setattr(factories, "synthetic_rgb", rgb)
    write_synthetic_dataset(root, EPISODES, seed=1, fps=FPS)
    ids = [e["episode_id"] for e in EPISODES]
    commit_split(root, "s", {"train": ids[:7], "test": ids[7:]})
    return root


def _control(root, tmp_path):
    paths = ensure_probes(root, "s", tmp_path / "probes", TINY)
    parts = {"test": load_items(root, "s", "test", TINY)}
    scores = control_scores(paths, parts, TINY)
    return scores, control_checks(scores, "test"), paths


def test_partners_shift_by_at_least_a_second_and_shuffle_across_episodes():
    episode = np.repeat([0, 1, 2], 10)
    frame = np.tile(np.arange(10), 3)
    fps = np.full(30, 4.0)
    shifted = partners(episode, frame, fps, "shifted")
    assert (shifted >= 0).all()
    assert (episode[shifted] == episode).all() and (np.abs(frame[shifted] - frame) >= 4).all()
    assert frame[shifted][0] == 4 and frame[shifted][9] == 5            # the nearest frame >= 1 s away
    shuffled = partners(episode, frame, fps, "shuffled", seed=3)
    assert (episode[shuffled] != episode).all()
    assert (partners(episode, frame, fps, "aligned") == np.arange(30)).all()
    short = partners(np.zeros(4, int), np.arange(4), np.full(4, 4.0), "shifted")   # < 1 s of frames: none
    assert (short == -1).all()
    with pytest.raises(ValueError, match="pairing"):
        partners(episode, frame, fps, "rolled")


def test_probe_is_saved_in_the_file_based_encoder_format(tmp_path):
    model = TactileGridRGB(**TINY.arch)
    save_probe(model, tmp_path / "enc.pt", {"pairing": "aligned"})
    enc = load_rgb_encoder(str(tmp_path / "enc.pt"))
    assert enc.info.kind == "state_dict" and len(enc.info.sha256) == 64
    rgb = torch.randint(0, 256, (2, 3, CANVAS, CANVAS), dtype=torch.uint8)
    tokens = enc(rgb)
    assert tokens.shape == (2, 14 * 14, 4)                                 # one token per canvas cell
    assert torch.allclose(tokens, model(rgb.float() / 255).flatten(2).transpose(1, 2))
    assert not any(p.requires_grad for p in enc.parameters())


def test_aligned_dataset_passes_the_misalignment_control(tmp_path, monkeypatch):
    root = _dataset(tmp_path / "aligned", monkeypatch, rgb_shift=0)
    scores, checks, paths = _control(root, tmp_path)
    assert scores["test"]["aligned"]["ratio"] < 0.5
    assert all(c["ok"] for c in checks), checks
    stamps = {p: path.stat().st_mtime_ns for p, path in paths.items()}
    assert ensure_probes(root, "s", tmp_path / "probes", TINY) == paths      # cached: reused, not retrained
    assert {p: path.stat().st_mtime_ns for p, path in paths.items()} == stamps


def test_a_version_that_changes_nothing_the_probes_read_keeps_them(tmp_path, monkeypatch):
    """A new version whose only change is its split list (or its number, time, parent) serves the
    probes the same bytes: no retraining. A version that changes the samples gets a new key."""
    root = _dataset(tmp_path / "ds", monkeypatch, rgb_shift=0)
    cfg = dataclasses.replace(TINY, steps=3)
    before = DatasetMetadata(root).manifest
    paths = ensure_probes(root, "s", tmp_path / "probes", cfg, pairings=("aligned",))
    stamp = paths["aligned"].stat().st_mtime_ns
    snap = open_snapshot(root)                                             # a new version holding the same
    same = split_path(root, "s").read_bytes()                              # samples and split: a no-op
    commit_parts(root, snap.parts(), {}, snap, "test: no-op version", splits=lambda episodes, sha: {"s": same})
    after = DatasetMetadata(root).manifest
    assert after["version"] == before["version"] + 1 and after != before
    assert content_record(after) == content_record(before)
    assert probes_cached(root, "s", tmp_path / "probes", cfg, pairings=("aligned",))
    assert ensure_probes(root, "s", tmp_path / "probes", cfg, pairings=("aligned",)) == paths
    assert paths["aligned"].stat().st_mtime_ns == stamp                    # reused, not retrained
    key = cache_key(root, "s", "train", cfg)
    remove_episodes(root, ["ep9"], dry_run=False, command="test: rm ep9")  # a test episode: the samples change
    assert cache_key(root, "s", "train", cfg) != key
    assert not probes_cached(root, "s", tmp_path / "probes", cfg, pairings=("aligned",))
    assert set(VERSION_RECORD_FIELDS) <= set(after) | {"parent"}           # the names are the manifest's


def test_rgb_shifted_by_a_second_in_the_data_fails_the_control(tmp_path, monkeypatch):
    """A sync bug: every RGB frame shows the scene 1 s later. Here each frame's pressure is drawn
    afresh, so the shifted frame says nothing and the required control fails. (In the sample world
    a 1 s shift stays learnable: rgb_pretrain.REQUIRED_CONTROLS.)"""
    root = _dataset(tmp_path / "shifted", monkeypatch, rgb_shift=int(FPS))
    scores, checks, _ = _control(root, tmp_path)
    assert not any(c["ok"] for c in checks), (scores, checks)
    assert any(c["required"] for c in checks)


def test_rgb_unrelated_to_touch_fails_the_control(tmp_path, monkeypatch):
    root = _dataset(tmp_path / "random", monkeypatch, rgb_shift=None)
    scores, checks, _ = _control(root, tmp_path)
    # the smoke fails on any failed required check
    assert not all(c["ok"] for c in checks if c["required"]), (scores, checks)


def test_torch_threads_are_restored():
    before = torch.get_num_threads()
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError):
        with torch_threads(1):
            raise RuntimeError("boom")
    assert torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before


def test_control_checks_use_the_margin_and_only_the_shuffled_one_is_required():
    def scores(aligned, shifted, shuffled):
        return {"test": {"aligned": {"ratio": aligned}, "shifted": {"ratio": shifted},
                         "shuffled": {"ratio": shuffled}}}
    assert all(c["ok"] for c in control_checks(scores(0.4, 0.4 + CONTROL_MARGIN + 0.01, 0.8)))
    checks = control_checks(scores(0.4, 0.4 + CONTROL_MARGIN - 0.01, 0.8))
    assert [c["ok"] for c in checks] == [False, True]
    assert [c["required"] for c in checks] == [False, True]                # shifted: reported
    assert [c["ok"] for c in control_checks(scores(0.4, 0.9, 0.4 + CONTROL_MARGIN - 0.01))] == [True, False]
    assert not any(c["ok"] for c in control_checks(scores(None, 0.9, 0.9)))


def test_model_control_checks_need_the_aligned_frame_to_win_by_the_margin():
    def scores(aligned, shifted, shuffled):
        return {"test": {"shifted": {"rmse": shifted, "aligned_rmse": aligned},
                         "shuffled": {"rmse": shuffled, "aligned_rmse": aligned}}}
    ok = model_control_checks(scores(0.08, 0.08 + MODEL_MARGIN + 0.001, 0.12))
    assert [c["ok"] for c in ok] == [True, True] and all(c["required"] for c in ok)
    # a model that ignores the frame scores the same whatever frame it gets: fails both
    assert not any(c["ok"] for c in model_control_checks(scores(0.08, 0.08, 0.08)))
    assert [c["ok"] for c in model_control_checks(scores(0.08, 0.08 + MODEL_MARGIN / 2, 0.12))] == [False, True]
    assert not any(c["ok"] for c in model_control_checks(scores(float("nan"), 0.1, None)))


class _Brightness:
    """RGB-to-tactile from the frame's brightness; with `features`, from a backbone whose output is the brightness
    (what the once-per-frame features path must reproduce)."""

    name = "brightness"

    def __init__(self, backbone: bool):
        self.backbone = backbone
        if backbone:
            self.rgb_features = lambda rgb: rgb.float().mean((1, 2, 3))

    def rgb_to_tactile(self, rgb, coverage, hand, features=None):
        level = rgb.float().mean((1, 2, 3)) if features is None else features
        return ((level - 40) / 200)[:, None, None, None].clamp(0, 1) * coverage


def test_paired_rgb2tactile_scores_each_pairing_on_the_items_with_a_partner(tmp_path, monkeypatch):
    root = _dataset(tmp_path / "ds", monkeypatch, rgb_shift=0)
    prep = prepare({"test": load_part(root, "s", "test"), "ood": load_part(root, "s", "test")}, cfg=EvalConfig())["test"]
    fps = episode_fps(root)
    # >= 2 s away in a 3 s episode: the middle frames have no shifted partner and are left out
    got = paired_rgb2tactile(_Brightness(backbone=True), prep, fps, ("shifted", "shuffled"), 2.0, seed=3)
    assert got == paired_rgb2tactile(_Brightness(backbone=False), prep, fps, ("shifted", "shuffled"), 2.0, seed=3)
    flat = {k: torch.cat([b[k] for b in prep.frames]) for k in prep.frames[0]}
    model = _Brightness(backbone=False)
    for pairing in ("shifted", "shuffled"):       # by the definition, one frame at a time
        src = partners(flat["episode"].numpy(), flat["frame"].numpy(), fps[flat["episode"].numpy()], pairing, 2.0, 3)
        keep = np.flatnonzero(src >= 0)
        assert got[pairing]["items"] == len(keep) > 0
        assert (len(keep) < len(src)) == (pairing == "shifted")

        def rmse(rgb_rows):
            cov, tac = flat["coverage"][keep].float(), flat["tactile"][keep].float()
            pred = model.rgb_to_tactile(flat["rgb"][rgb_rows], cov, flat["hand"][keep])
            return float((((pred - tac) ** 2 * cov).flatten(1).sum(1) / cov.flatten(1).sum(1)).sqrt().mean())
        assert got[pairing]["aligned_rmse"] == pytest.approx(rmse(keep), rel=1e-5)
        assert got[pairing]["rmse"] == pytest.approx(rmse(src[keep]), rel=1e-5)
    assert got["shuffled"]["rmse"] > got["shuffled"]["aligned_rmse"] + 0.05     # the frame is read
