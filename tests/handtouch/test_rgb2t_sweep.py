"""handtouch.rgb2t_sweep: stages 2-3 from one stage-1 checkpoint, scored aligned / zeros /
mis-paired, on a tiny synthetic dataset (the "RGB prior" numbers in docs/HANDTOUCH.md come from it)."""

import json
import math

import pytest
import torch

from handtouch.config import load_train_config
from handtouch.rgb2t_sweep import main, seed_stage1
from handtouch.rgb_encoder import TactileGridRGB
from handtouch.rgb_pretrain import save_probe
from handtouch.train import read_checkpoint, train
from tests.factories import TRAIN_EPISODES, write_synthetic_dataset
from tests.factories.train import TINY, write_toml

PROBE_ARCH = {"size": 16, "width": 8, "channels": 4, "grid": 14, "hidden": 16}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A dataset with split `s` (test + ood), a tiny config, its stage-1 checkpoint and a probe file."""
    tmp = tmp_path_factory.mktemp("sweep")
    root = write_synthetic_dataset(tmp / "ds", TRAIN_EPISODES, seed=3, fps=4.0)
    from htdata.curate.split import make_split
    make_split(root, ood_tasks=["grab"], test_ratio=0.5, seed=0, name="s")
    config = tmp / "tiny.toml"
    write_toml(config, {**TINY, "data_root": str(root), "stage1": {**TINY["stage1"], "steps": 2}})
    save_probe(TactileGridRGB(**PROBE_ARCH), tmp / "probe.pt", {"pairing": "aligned"})
    # as in the smoke: stage 1 trained next to the same frozen RGB encoder
    train(load_train_config(config, [f'out_dir="{tmp / "s1"}"', "stages=[1]", f'rgb_encoder="{tmp / "probe.pt"}"']),
          on_record=lambda r: None)
    return {"root": root, "config": config, "stage1": tmp / "s1" / "stage1.pt", "probe": tmp / "probe.pt"}


def _run(trained, out, *extra):
    return main(["--config", str(trained["config"]), "--stage1", str(trained["stage1"]),
                 "--rgb-encoder", str(trained["probe"]), "--dataset", str(trained["root"]), "--split", "s",
                 "--out", str(out), "--seeds", "0,1", "--max-items", "6", *extra])


def test_sweep_scores_every_seed_stage_and_pairing(trained, tmp_path, capsys):
    assert _run(trained, tmp_path / "sw", "--set", "model.rgb_prior=true") == 0
    summary = json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert set(summary["seeds"]) == {"0", "1"}
    for seed in ("0", "1"):
        for stage in ("stage2", "stage3"):
            for part in ("test", "ood"):
                got = summary["seeds"][seed][stage][part]
                # the probe's own upsampled map is scored because the encoder has a readout
                assert set(got) == {"aligned", "shifted", "shuffled", "zeros", "probe"}
                assert all(math.isfinite(v) and v >= 0 for v in got.values()), got
        # each seed starts from the SAME stage-1 weights and trains only stages 2 and 3
        assert read_checkpoint(tmp_path / "sw" / f"seed{seed}" / "stage3.pt")["done"]
        seeded = read_checkpoint(tmp_path / "sw" / f"seed{seed}" / "stage1.pt")["model"]
        source = read_checkpoint(trained["stage1"])["model"]
        assert all(torch.equal(seeded[k], v) for k, v in source.items() if k.startswith("encoder."))
    s0, s1 = (summary["seeds"][s]["stage3"]["test"]["aligned"] for s in ("0", "1"))
    assert s0 != s1                                        # the seed reaches training
    assert "seed 1 after stage 3 ood:" in capsys.readouterr().out


def test_zeros_is_the_all_zeros_score_whatever_the_model(trained, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _run(trained, a) == 0 and _run(trained, b, "--set", "model.rgb_prior=true") == 0
    za = json.loads((a / "summary.json").read_text())["seeds"]["0"]["stage3"]
    zb = json.loads((b / "summary.json").read_text())["seeds"]["0"]["stage3"]
    assert za["test"]["zeros"] == zb["test"]["zeros"] and za["ood"]["zeros"] == zb["ood"]["zeros"]


def test_seed_stage1_copies_the_stage1_weights(trained, tmp_path):
    cfg = load_train_config(trained["config"], [f'rgb_encoder="{trained["probe"]}"', "model.rgb_prior=true"])
    seed_stage1(trained["stage1"], cfg, tmp_path)
    src, dst = read_checkpoint(trained["stage1"])["model"], read_checkpoint(tmp_path / "stage1.pt")["model"]
    for k, v in src.items():
        if not k.startswith("rgb_encoder."):
            assert torch.equal(dst[k], v), k


def test_stage1_of_another_model_is_refused_by_name(trained, tmp_path):
    cfg = load_train_config(trained["config"], ['model.encoder="cnn"'])
    with pytest.raises(ValueError, match="keys the configured model does not have"):
        seed_stage1(trained["stage1"], cfg, tmp_path)
    cfg = load_train_config(trained["config"], ["model.dim=48", f'rgb_encoder="{trained["probe"]}"'])
    with pytest.raises(ValueError, match="stage-1 weights shaped unlike"):
        seed_stage1(trained["stage1"], cfg, tmp_path)
    # another RGB encoder is fine: the frozen encoder always comes from --rgb-encoder, and the
    # RGB projection (untrained in stage 1) is shaped for it afresh
    seed_stage1(trained["stage1"], load_train_config(trained["config"], ["model.rgb_prior=false"]), tmp_path)
    assert read_checkpoint(tmp_path / "stage1.pt")["model"]["rgb_proj.proj.weight"].shape[1] == 64
