"""A tiny HandTouch training config (TINY) and its TOML writer, shared by the compare and sweep tests."""

from __future__ import annotations

import json

TINY = {
    "data_root": "", "out_dir": "unused", "rgb_encoder": "random:0", "split": "s", "device": "cpu",
    "workers": 0, "threads": 1, "batch_size": 4, "eval_batch_size": 2, "log_every": 1, "checkpoint_every": 50,
    "seed": 1,
    "model": {"encoder": "vit", "patch": 32, "dim": 32, "depth": 1, "heads": 2, "mlp_ratio": 2.0, "code_dim": 8,
              "codebook_size": 16, "vq_usage_decay": 0.9, "decoder_depth": 1, "decoder_channels": 16,
              "fusion_depth": 1, "temporal_depth": 1, "predictor_depth": 1, "cnn_widths": [8, 16, 24],
              "resnet_widths": [8, 16, 24, 32], "vqvae_widths": [8, 16, 24]},
    "stage1": {"steps": 1, "lr": 1e-3, "warmup_steps": 1, "trainable": ["encoder", "vq", "decoder"]},
    "stage2": {"steps": 1, "lr": 1e-3, "warmup_steps": 1,
               "trainable": ["encoder", "vq", "decoder", "rgb_proj", "hand_token", "fusion"]},
    "stage3": {"steps": 1, "lr": 1e-3, "warmup_steps": 1,
               "trainable": ["temporal", "predictor", "rgb_proj", "hand_token", "vq", "decoder"]},
}


def write_toml(path, data: dict) -> None:
    """A flat TOML writer for TINY (JSON scalars and lists are valid TOML values)."""
    top = [f"{k} = {json.dumps(v)}" for k, v in data.items() if not isinstance(v, dict)]
    tables = [f"\n[{k}]\n" + "\n".join(f"{kk} = {json.dumps(vv)}" for kk, vv in v.items())
              for k, v in data.items() if isinstance(v, dict)]
    path.write_text("\n".join(top) + "\n" + "\n".join(tables) + "\n")
