"""Tokens (B, g*g, D) -> tactile map (B, 1, 224, 224) in [0, 1].

Attention blocks mix tokens, then 2x upsampling steps (nearest + 3x3 conv, halving
channels) up to a quarter of the canvas; the last 4x is a 3x3 conv to 16 channels +
PixelShuffle (convs at full 224x224 resolution cost 3x the rest of the model on
CPU). A sigmoid bounds the output to [0, 1].
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn

from htdata.format import CANVAS

from .encoders import transformer_stack

SHUFFLE_DOUBLINGS = 2   # the last 4x of upsampling is a PixelShuffle


class TactileDecoder(nn.Module):
    def __init__(self, dim: int, grid: int, depth: int, heads: int, mlp_ratio: float, channels: int):
        super().__init__()
        factor = CANVAS // grid
        if grid * factor != CANVAS or factor & (factor - 1):
            raise ValueError(f"decoder: grid {grid} must reach {CANVAS} by doubling")
        self.grid = grid
        self.blocks = transformer_stack(dim, heads, mlp_ratio, depth)
        self.norm = nn.LayerNorm(dim)
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
        nn.init.constant_(self.head[0].bias, -2.0)   # start near the mostly-empty maps (sigmoid(-2) = 0.12)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        b, n, d = tokens.shape
        if n != self.grid * self.grid:
            raise ValueError(f"decoder expects {self.grid * self.grid} tokens, got {n}")
        x = self.norm(self.blocks(tokens))
        fmap = x.transpose(1, 2).reshape(b, d, self.grid, self.grid)
        return torch.sigmoid(self.head(self.upsample(self.to_map(fmap))))
