"""The interface every model scored by HT-Bench implements.

HandTouch (ViT + factorised VQ) and the baselines (CNN, ResNet-18-style
encoders trained the same way) all expose these four calls, so
`handtouch.bench.evaluate` scores any of them on the four tracks.

Tensor conventions (batch B):
  tactile  (B,1,224,224) float32 in [0,1]
  coverage (B,1,224,224) float32, 1 where the glove has a sensor
  regions  (B,224,224)   uint8 part ids (0 outside, 1 thumb .. 6 palm)
  mask     (B,1,224,224) float32, 1 = hidden from the model (to inpaint)
  rgb      (B,3,224,224) uint8 or float in [0,1]; windows add a time axis:
           rgb_window (B,3,3,224,224) = frames T-2..T, tactile_window
           (B,2,1,224,224) = tactile T-2..T-1
  hand     (B,) long, 0 = left, 1 = right
"""

from __future__ import annotations

from typing import Protocol

import torch


class TactileModel(Protocol):
    name: str

    def embed(self, tactile: torch.Tensor, coverage: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
        """(B, E) embedding used for 1-vs-20 retrieval (cosine similarity)."""

    def inpaint(self, tactile: torch.Tensor, coverage: torch.Tensor, mask: torch.Tensor,
                rgb: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
        """Reconstruct the full map (B,1,224,224) from the visible part + RGB."""

    def rgb_to_tactile(self, rgb: torch.Tensor, coverage: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
        """Complete masking: predict the map (B,1,224,224) from RGB alone."""

    def predict_next(self, rgb_window: torch.Tensor, tactile_window: torch.Tensor,
                     coverage: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
        """Predict t_T (B,1,224,224) from v_{T-2..T} and t_{T-2..T-1}."""
