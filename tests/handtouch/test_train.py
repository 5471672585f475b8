import json
import logging
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import Dataset

from handtouch.config import (
    MODULE_NAMES,
    StageConfig,
    TrainConfig,
    apply_overrides,
    load_train_config,
    parse_override,
    train_config_from_dict,
)
from handtouch.distributed import StepBatchSampler, init_distributed
from handtouch.resources import config_file
from handtouch.stages import (
    FRAMES,
    MASK,
    WINDOWS,
    MaskedFusion,
    NextFramePrediction,
    Reconstruction,
    StepInfo,
    build_stages,
)
from handtouch.steploop import lr_at
from handtouch.train import (
    JsonlLog,
    TrainData,
    build_model,
    load_data,
    load_model,
    main,
    read_checkpoint,
    run_stage,
    train,
)
from tests.factories import TRAIN_EPISODES as EPISODES
from tests.factories import write_synthetic_dataset

TINY_MODEL = {"encoder": "vit", "patch": 32, "dim": 32, "depth": 1, "heads": 2, "mlp_ratio": 2.0,
              "code_dim": 8, "codebook_size": 16, "vq_usage_decay": 0.9, "decoder_depth": 1,
              "decoder_channels": 16, "fusion_depth": 1, "temporal_depth": 1, "predictor_depth": 1}


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory):
    root = write_synthetic_dataset(tmp_path_factory.mktemp("ds") / "ds", EPISODES, seed=3)
    from htdata.curate.split import make_split
    make_split(root, ood_tasks=["grab"], test_ratio=0.5, seed=0, name="s")
    return root


def tiny_config(root, out, **over) -> TrainConfig:
    data = {"data_root": str(root), "out_dir": str(out), "rgb_encoder": "random:0", "device": "cpu",
            "workers": 0, "batch_size": 4, "eval_batch_size": 4, "log_every": 5, "checkpoint_every": 6,
            "seed": 1, "model": dict(TINY_MODEL),
            "stage1": {"steps": 30, "lr": 3e-3, "warmup_steps": 2, "trainable": ["encoder", "vq", "decoder"]},
            "stage2": {"steps": 4, "lr": 1e-3, "warmup_steps": 1,
                       "trainable": ["encoder", "vq", "decoder", "rgb_proj", "hand_token", "fusion"]},
            "stage3": {"steps": 4, "lr": 1e-3, "warmup_steps": 1,
                       "trainable": ["temporal", "predictor", "rgb_proj", "hand_token", "vq", "decoder"]}}
    return train_config_from_dict(apply_overrides(data, [f"{k}={v}" for k, v in over.items()]))


def read_log(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]


def test_three_stages_train_log_and_write_metrics(dataset_root, tmp_path):
    out = tmp_path / "run"
    cfg = tiny_config(dataset_root, out, workers=1, split='"s"')
    metrics = train(cfg)
    log = read_log(out)
    s1 = [r for r in log if r.get("stage") == 1 and "loss" in r]
    assert len(s1) == 6                              # every 5 of 30 steps
    assert s1[-1]["recon"] < 0.5 * s1[0]["recon"]    # reconstruction loss goes down
    assert all(r["steps_per_s"] > 0 and r["samples_per_s"] == pytest.approx(4 * r["steps_per_s"]) for r in s1)
    for n in (1, 2, 3):
        ck = read_checkpoint(out / f"stage{n}.pt")
        assert ck["done"] and ck["step"] == cfg.stage(n).steps
    on_disk = json.loads((out / "metrics.json").read_text())
    assert on_disk == json.loads(json.dumps(metrics))
    assert set(on_disk["stages"]) == {"1", "2", "3"}
    assert {"visible", "masked"} <= set(on_disk["stages"]["2"]["final"])
    assert "next" in on_disk["stages"]["3"]["final"]
    assert 0 < on_disk["recon_rmse"] < 1 and on_disk["steps_per_s"] > 0
    assert 1 <= on_disk["codebook"]["perplexity"] <= 16
    assert on_disk["heldout_source"] == "part 'test' of split 's'"
    assert on_disk["rgb_encoder"]["spec"] == "random:0"

    model = load_model(out / "stage3.pt")
    assert not model.training
    state = read_checkpoint(out / "stage3.pt")["model"]
    assert all(torch.equal(v, state[k]) for k, v in model.state_dict().items())

    # a re-run skips the finished stages and trains nothing
    train(cfg)
    events = [r.get("event") for r in read_log(out)]
    assert events.count("stage_skipped") == 3


class FailAfter(Dataset):
    """Wraps a dataset and raises after `limit` items: a crash in the middle of a stage."""

    def __init__(self, inner, limit):
        self.inner, self.limit, self.calls = inner, limit, 0

    def __len__(self):
        return len(self.inner)

    def __getitem__(self, i):
        self.calls += 1
        if self.calls > self.limit:
            raise RuntimeError("simulated crash")
        return self.inner[i]


def test_resume_from_checkpoint_matches_an_uninterrupted_run(dataset_root, tmp_path):
    over = {"stages": "[1, 2]", "stage1.steps": 12, "stage2.steps": 12}
    full_cfg = tiny_config(dataset_root, tmp_path / "a", **over)
    train(full_cfg)

    cfg = tiny_config(dataset_root, tmp_path / "b", **over)
    data = load_data(cfg)
    crashing = TrainData(data.frames, data.windows, data.eval_frames, data.eval_source, constants=data.constants)
    crashing.frames = FailAfter(data.frames, limit=4 * (12 + 9))   # dies in stage 2, step 9
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(cfg, crashing)
    assert read_checkpoint(tmp_path / "b" / "stage1.pt")["done"]
    partial = read_checkpoint(tmp_path / "b" / "stage2.pt")
    assert not partial["done"] and partial["step"] == 6

    train(cfg)
    events = [r.get("event") for r in read_log(tmp_path / "b")]
    assert "stage_resumed" in events
    a = read_checkpoint(tmp_path / "a" / "stage2.pt")["model"]
    b = read_checkpoint(tmp_path / "b" / "stage2.pt")["model"]
    for k in a:
        assert torch.allclose(a[k], b[k], atol=1e-6), k


def test_later_stage_needs_the_previous_checkpoint(dataset_root, tmp_path):
    cfg = tiny_config(dataset_root, tmp_path / "c", stages="[2]")
    with pytest.raises(FileNotFoundError, match="stage1.pt"):
        train(cfg)


def test_step_batch_sampler_is_deterministic_disjoint_and_resumable():
    full = list(StepBatchSampler(10, 2, seed=4, start_step=0, stop_step=7))
    assert list(StepBatchSampler(10, 2, seed=4, start_step=3, stop_step=7)) == full[3:]
    for epoch_batches in (full[0:5], full[5:7]):
        flat = [i for b in epoch_batches for i in b]
        assert len(flat) == len(set(flat))            # no repeats inside an epoch
    r0 = list(StepBatchSampler(9, 2, seed=1, start_step=0, stop_step=2, rank=0, world_size=2))
    r1 = list(StepBatchSampler(9, 2, seed=1, start_step=0, stop_step=2, rank=1, world_size=2))
    for b0, b1 in zip(r0, r1):
        assert not set(b0) & set(b1) and len(b0) == len(b1) == 2
    with pytest.raises(ValueError, match="fewer than one global batch"):
        StepBatchSampler(3, 2, seed=0, start_step=0, stop_step=1, world_size=2)


def test_lr_schedule_warmup_then_cosine():
    assert lr_at(0, 100, 1.0, 10) == pytest.approx(0.1)
    assert lr_at(9, 100, 1.0, 10) == pytest.approx(1.0)
    assert lr_at(10, 100, 1.0, 10) == pytest.approx(1.0)
    assert lr_at(100, 100, 1.0, 10) == pytest.approx(0.1)
    assert np.all(np.diff([lr_at(s, 100, 1.0, 10) for s in range(10, 101)]) <= 1e-12)


def test_config_files_load_and_reject_bad_input(tmp_path):
    repo = Path(__file__).resolve().parents[2]
    smoke = load_train_config(repo / "configs" / "smoke.toml")
    full = load_train_config(repo / "configs" / "full.toml", ["model.depth=8"])
    assert smoke.model.encoder == "vit" and full.model.depth == 8 and full.model.codebook_size == 2048
    assert parse_override("stage1.steps=7") == (["stage1", "steps"], 7)
    assert parse_override("rgb_encoder=random:3") == (["rgb_encoder"], "random:3")
    base = (repo / "configs" / "smoke.toml").read_text()
    cases = {
        "unknown keys": base + "\nbogus = 1\n",
        "unknown keys ": base.replace("[model]", "[model]\ndimm = 3"),
        "lambda_mask": base.replace("lambda_mask = 1.0", "lambda_mask = 0.4"),
        "uses per code": base.replace("codebook_size = 64", "codebook_size = 4096"),
        "trainable has unknown": base.replace('trainable = ["encoder", "vq", "decoder"]', 'trainable = ["encoderr"]'),
        "stages": base.replace("stages = [1, 2, 3]", "stages = [2, 1]"),
    }
    for msg, text in cases.items():
        path = tmp_path / "c.toml"
        path.write_text(text)
        with pytest.raises(ValueError, match=msg.strip()):
            load_train_config(path)
    missing = base.replace('rgb_encoder = "random:0"', "")
    (tmp_path / "m.toml").write_text(missing)
    with pytest.raises(ValueError, match="rgb_encoder"):
        load_train_config(tmp_path / "m.toml")
    with pytest.raises(FileNotFoundError):
        load_train_config(tmp_path / "absent.toml")
    assert main(["--config", str(tmp_path / "c.toml")]) == 2     # CLI reports config errors, exit 2
    assert main(["--config", "no_such_config"]) == 2              # a bare name is looked up among shipped configs
    assert load_train_config(config_file("smoke")).model.codebook_size == smoke.model.codebook_size


def test_cli_runs_with_overrides(dataset_root, tmp_path, capsys):
    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "cli"
    threads = torch.get_num_threads()
    rc = main(["--config", str(repo / "configs" / "smoke.toml"), "--set", f'data_root="{dataset_root}"',
               "--set", f'out_dir="{out}"', "--set", "stages=[1]", "--set", "stage1.steps=2",
               "--set", "workers=0", "--set", "batch_size=4", "--set", "model.codebook_size=16",
               "--set", "device=cpu", "--set", "threads=1"])
    assert rc == 0
    assert torch.get_num_threads() == threads       # the training thread budget does not leak out
    assert json.loads((out / "metrics.json").read_text())["stages"]["1"]["steps"] == 2
    assert '"event": "done"' in capsys.readouterr().out


def test_single_frame_episodes_give_a_clear_stage3_error(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds1", [
        {"episode_id": f"e{i}", "task": "t", "scene": "s", "hands": ("right",), "num_frames": 1} for i in range(4)])
    cfg = tiny_config(root, tmp_path / "o", **{"stage1.steps": 1, "stage2.steps": 1})
    with pytest.raises(ValueError, match=r"stage 3 \(window"):
        train(cfg)


class SpyStage(Reconstruction):
    """Stage 1 that records what the generic loop asks of it and adds a term of its own."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self.prepared, self.losses = [], 0

    def prepare(self, batch, at):
        self.prepared.append((at.step, at.steps, at.rank))
        return batch

    def loss(self, model, batch):
        self.losses += 1
        loss, terms = super().loss(model, batch)
        return loss, {**terms, "spy": torch.tensor(float(self.losses))}


def test_generic_loop_runs_whatever_the_stage_object_says(dataset_root, tmp_path):
    cfg = tiny_config(dataset_root, tmp_path / "spy", stages="[1]", log_every=3, **{"stage1.steps": 3})
    stage = SpyStage(StageConfig(steps=3, lr=1e-3, warmup_steps=1, trainable=["encoder", "decoder"]))
    model = build_model(cfg)
    records = []
    (tmp_path / "spy").mkdir()
    summary = run_stage(stage, model, cfg, load_data(cfg), init_distributed("cpu"), tmp_path / "spy",
                        JsonlLog(None, records.append))
    assert stage.losses == 3 and stage.prepared == [(0, 3, 0), (1, 3, 0), (2, 3, 0)]
    assert summary["final"]["spy"] == pytest.approx(2.0)          # mean of the stage's own term over 3 steps
    assert [r["step"] for r in records] == [3] and "recon" in records[0]
    assert model.frozen == {n for n in MODULE_NAMES if n not in ("encoder", "decoder")}   # its own names
    assert read_checkpoint(tmp_path / "spy" / "stage1.pt")["done"]


def test_stage_objects_from_the_config(dataset_root, tmp_path):
    cfg = tiny_config(dataset_root, tmp_path / "x")
    stages = build_stages(cfg)
    assert [type(s) for s in stages] == [Reconstruction, MaskedFusion, NextFramePrediction]
    assert [s.data for s in stages] == [FRAMES, FRAMES, WINDOWS]
    for s in stages:
        assert s.cfg is cfg.stage(s.number) and s.weights is cfg.loss
        assert set(s.trainable) | set(s.frozen) == set(MODULE_NAMES) and not set(s.trainable) & set(s.frozen)
    assert stages[1].frozen == ("temporal", "predictor")
    assert stages[2].frozen == ("encoder", "fusion")

    # stage 2's mask depends only on (seed, step, rank): a resumed run redraws the same one
    regions = torch.zeros(4, 224, 224, dtype=torch.uint8)
    regions[:, :100] = 1
    regions[:, 100:] = 6
    batch = {"regions": regions}
    a = stages[1].prepare(batch, StepInfo(2, 4, 0))[MASK]
    assert a.shape == (4, 1, 224, 224) and MASK not in batch
    assert torch.equal(a, stages[1].prepare(batch, StepInfo(2, 4, 0))[MASK])
    draws = [stages[1].prepare(batch, StepInfo(s, 4, r))[MASK] for s in range(4) for r in range(2)]
    assert any(not torch.equal(a, d) for d in draws)
    assert stages[0].prepare(batch, StepInfo(0, 4)) is batch      # stage 1 needs nothing added


def test_train_reports_records_through_logging_or_a_callback(dataset_root, tmp_path, capsys, caplog):
    cfg = tiny_config(dataset_root, tmp_path / "l", stages="[1]", **{"stage1.steps": 2})
    with caplog.at_level(logging.INFO, logger="handtouch.train"):
        train(cfg)
    assert capsys.readouterr().out == ""                       # the library never prints
    logged = [json.loads(r.getMessage()) for r in caplog.records if r.name == "handtouch.train"]
    assert logged == read_log(tmp_path / "l")                  # same records as log.jsonl
    got = []
    train(tiny_config(dataset_root, tmp_path / "m", stages="[1]", **{"stage1.steps": 2}), on_record=got.append)
    assert [r.get("event") for r in got] == ["start", None, "done"] and got == read_log(tmp_path / "m")


def test_training_bench_section_plugin(dataset_root, tmp_path):
    """The "training" section `htdata bench` discovers by entry point, run in quick mode."""
    import tomllib
    from importlib.metadata import EntryPoint
    from types import SimpleNamespace

    repo = Path(__file__).resolve().parents[2]
    declared = tomllib.loads((repo / "pyproject.toml").read_text())["project"]["entry-points"]
    value = declared["htdata.bench_sections"]["training"]
    section = EntryPoint("training", value, "htdata.bench_sections").load()
    result = section(SimpleNamespace(dataset=dataset_root, work=tmp_path, quick=True, seed=0))
    json.dumps(result, allow_nan=False)                              # JSON-able, finite
    assert [r["precision"] for r in result["rows"]] == ["fp32", "bf16 autocast"]
    assert all(r["steps"] == 2 and r["steps_per_s"] > 0 and 0 < r["recon_rmse"] < 1 for r in result["rows"])
    assert result["bf16_speedup"] == pytest.approx(result["rows"][1]["steps_per_s"] / result["rows"][0]["steps_per_s"])
    assert not result["warmup_run"] and Path(result["config"]).name == "smoke.toml"
    for r in result["rows"]:    # the per-step breakdown: data wait + host = the step on a CPU
        assert r["data_wait_ms_per_step"] > 0 and r["host_ms_per_step"] > 0 and "device_ms_per_step" not in r
        assert r["data_wait_ms_per_step"] + r["host_ms_per_step"] == pytest.approx(r["wall_ms_per_step"], rel=0.05)
    md = result["markdown"]
    assert "| data wait ms |" in md
    assert md.count("\n| fp32 |") == 1 and "| bf16 autocast |" in md and "bf16 / fp32 speed:" in md


def test_ablation_switches_load_from_overrides(tmp_path):
    cfg = load_train_config(config_file("smoke"), ["model.codebook=false", "model.vision=false",
                                                   "masking.curriculum=false"])
    assert (cfg.model.codebook, cfg.model.vision, cfg.masking.curriculum) == (False, False, False)
    default = load_train_config(config_file("smoke"))
    assert (default.model.codebook, default.model.vision, default.masking.curriculum) == (True, True, True)
    with pytest.raises(ValueError, match="model.codebook"):
        load_train_config(config_file("smoke"), ['model.codebook="no"'])
    with pytest.raises(ValueError, match="masking.curriculum"):
        load_train_config(config_file("smoke"), ["masking.curriculum=1"])


def test_baseline_and_design_switches_load_and_change_the_config():
    base = load_train_config(config_file("compare_smoke"))
    assert (base.loss.stage3_replay, base.loss.stage3_vq, base.model.mask_channel) == (0.0, False, False)
    smoke = load_train_config(config_file("smoke"))
    assert (smoke.loss.stage3_replay, smoke.loss.stage3_vq) == (1.0, True)    # the smoke's documented opt-in
    cfg = load_train_config(config_file("compare_smoke"), ["loss.stage3_replay=0.5", "loss.stage3_vq=true",
                                                           "model.mask_channel=true", 'model.encoder="vqvae"'])
    assert (cfg.loss.stage3_replay, cfg.loss.stage3_vq, cfg.model.mask_channel) == (0.5, True, True)
    assert cfg.model.decoder_kind == "conv" and cfg.model.quantised and cfg.model.num_tokens == 196
    starved = ["batch_size=1", "model.codebook_size=1024"]      # 196 tokens / 1024 codes < 2 uses per code
    plain = load_train_config(config_file("compare_smoke"), ['model.encoder="vit_plain"', *starved])
    assert plain.model.decoder_kind == "linear" and not plain.model.quantised   # no codebook-load check applies
    with pytest.raises(ValueError, match="uses per code"):
        load_train_config(config_file("compare_smoke"), starved)
    with pytest.raises(ValueError, match="stage3_replay"):
        load_train_config(config_file("compare_smoke"), ["loss.stage3_replay=-1"])


def test_stage3_switches_change_what_stage3_trains(dataset_root, tmp_path):
    """Paper loss: stage 3 leaves the codebook exactly as stage 2 left it (no gradient, no weight
    decay); with the VQ terms it moves. Dead-code restarts are off (threshold 0) to isolate that."""
    moved = {}
    for vq in (False, True):
        out = tmp_path / f"vq{vq}"
        cfg = tiny_config(dataset_root, out, **{"stage1.steps": 4, "loss.stage3_vq": str(vq).lower(),
                                                "model.vq_dead_threshold": 0.0})
        train(cfg)
        before = read_checkpoint(out / "stage2.pt")["model"]["vq.codebook"]
        after = read_checkpoint(out / "stage3.pt")["model"]["vq.codebook"]
        moved[vq] = not torch.equal(before, after)
    assert moved == {False: False, True: True}
