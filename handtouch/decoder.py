"""Tokens (B, g*g, D) -> tactile map (B, 1, 224, 224) in [0, 1].

TactileDecoder (HandTouch's, mixer "attention"): attention blocks mix tokens, then 2x
upsampling steps (nearest + 3x3 conv, halving channels) up to a quarter of the canvas; the
last 4x is a 3x3 conv to 16 channels + PixelShuffle (convs at full 224x224 resolution cost 3x
the rest of the model on CPU). With mixer "conv" (the VQ-VAE baseline) a 3x3 conv + VQ-VAE
residual blocks on the token grid replace the attention blocks; the upsampling is the same.
LinearPatchDecoder (the plain-ViT baseline): one linear map per token to its patch's pixels
(MAE's pixel head). A sigmoid bounds every output to [0, 1]. `build_tactile_decoder` picks
one from ModelConfig.decoder_kind.
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn

from htdata.format.canvas import CANVAS

from .config import ModelConfig
from .encoders import ResidualStack, transformer_stack

SHUFFLE_DOUBLINGS = 2   # the last 4x of upsampling is a PixelShuffle
EMPTY_BIAS = -2.0       # start near the mostly-empty maps (sigmoid(-2) = 0.12)


def _check_tokens(tokens: torch.Tensor, grid: int) -> None:
    if tokens.shape[1] != grid * grid:
        raise ValueError(f"decoder expects {grid * grid} tokens, got {tokens.shape[1]}")


class TactileDecoder(nn.Module):
    def __init__(self, dim: int, grid: int, depth: int, heads: int, mlp_ratio: float, channels: int,
                 mixer: str = "attention"):
        super().__init__()
        factor = CANVAS // grid
        if grid * factor != CANVAS or factor & (factor - 1):
            raise ValueError(f"decoder: grid {grid} must reach {CANVAS} by doubling")
        if mixer not in ("attention", "conv"):
            raise ValueError(f"decoder mixer must be attention or conv, got {mixer!r}")
        self.grid = grid
        self.mixer = mixer
        if mixer == "attention":
            self.blocks = transformer_stack(dim, heads, mlp_ratio, depth)
            self.norm = nn.LayerNorm(dim)
        else:
            self.blocks = nn.Sequential(nn.Conv2d(dim, dim, 3, padding=1), ResidualStack(dim, max(dim // 2, 8), depth))
            self.norm = nn.Identity()
        self.to_map = nn.Conv2d(dim, channels, 1)
        doublings = int(math.log2(factor))
        shuffle = 2 ** min(doublings, SHUFFLE_DOUBLINGS)
        ups, c = [], channels
        for _ in range(doublings - int(math.log2(shuffle))):
            c_out = max(c // 2, 8)
            ups += [nn.Upsample(scale_factor=2, mode="nearest"),
                    nn.Conv2d(c, c_out, 3, padding=1), nn.GroupNorm(min(8, c_out), c_out), nn.GELU()]
            c = c_out
        self.upsample = nn.Sequential(*ups)
        self.head = nn.Sequential(nn.Conv2d(c, shuffle * shuffle, 3, padding=1), nn.PixelShuffle(shuffle))
        nn.init.constant_(self.head[0].bias, EMPTY_BIAS)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        _check_tokens(tokens, self.grid)
        b, n, d = tokens.shape
        if self.mixer == "attention":
            x = self.norm(self.blocks(tokens))
            fmap = x.transpose(1, 2).reshape(b, d, self.grid, self.grid)
        else:
            fmap = self.blocks(tokens.transpose(1, 2).reshape(b, d, self.grid, self.grid))
        return torch.sigmoid(self.head(self.upsample(self.to_map(fmap))))


class LinearPatchDecoder(nn.Module):
    """LayerNorm + one linear map per token to its (224/g)^2 patch pixels, reassembled in grid order."""

    def __init__(self, dim: int, grid: int):
        super().__init__()
        if CANVAS % grid:
            raise ValueError(f"decoder: grid {grid} must divide {CANVAS}")
        self.grid, self.patch = grid, CANVAS // grid
        self.norm = nn.LayerNorm(dim)
        self.to_pixels = nn.Linear(dim, self.patch * self.patch)
        nn.init.constant_(self.to_pixels.bias, EMPTY_BIAS)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        _check_tokens(tokens, self.grid)
        b, g, p = tokens.shape[0], self.grid, self.patch
        pixels = self.to_pixels(self.norm(tokens)).reshape(b, g, g, p, p)
        return torch.sigmoid(pixels.permute(0, 1, 3, 2, 4).reshape(b, 1, g * p, g * p))


def build_tactile_decoder(cfg: ModelConfig, grid: int) -> nn.Module:
    if cfg.decoder_kind == "linear":
        return LinearPatchDecoder(cfg.dim, grid)
    return TactileDecoder(cfg.dim, grid, cfg.decoder_depth, cfg.heads, cfg.mlp_ratio, cfg.decoder_channels,
                          mixer=cfg.decoder_kind)
