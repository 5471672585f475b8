"""A tiny HandTouch model, a batch of frames and a stage of it: shared by the model and step-loop tests."""

import torch

from handtouch.config import ModelConfig, StageConfig
from handtouch.model import HandTouch
from handtouch.rgb_encoder import load_rgb_encoder
from handtouch.stages import STAGES

STAGE_TRAINABLE = {
    1: ["encoder", "vq", "decoder"],
    2: ["encoder", "vq", "decoder", "rgb_proj", "hand_token", "fusion"],
    3: ["temporal", "predictor", "rgb_proj", "hand_token", "vq", "decoder"],
}


def tiny_cfg(encoder="vit", **kw):
    base = dict(encoder=encoder, patch=32, dim=32, depth=1, heads=2, mlp_ratio=2.0, code_dim=8,
                codebook_size=16, decoder_depth=1, decoder_channels=16, fusion_depth=1,
                temporal_depth=1, predictor_depth=1)
    base.update(kw)
    return ModelConfig(**base)


def tiny_model(encoder="vit", seed=0, **kw):
    torch.manual_seed(seed)
    return HandTouch(tiny_cfg(encoder, **kw), load_rgb_encoder("random:0"))


def frame_batch(b=2, seed=0, coverage=None):
    g = torch.Generator().manual_seed(seed)
    cov = torch.ones(b, 1, 224, 224) if coverage is None else coverage
    regions = torch.zeros(b, 224, 224, dtype=torch.uint8)
    regions[:, :112, :112] = 1
    regions[:, 112:, :] = 6
    return {"tactile": torch.rand(b, 1, 224, 224, generator=g) * cov, "coverage": cov, "regions": regions,
            "rgb": torch.randint(0, 256, (b, 3, 224, 224), generator=g, dtype=torch.uint8),
            "hand": torch.tensor([0, 1] * (b // 2) + [1] * (b % 2))}


def make_stage(n, weights=None):
    return STAGES[n](StageConfig(trainable=STAGE_TRAINABLE[n]), weights)
