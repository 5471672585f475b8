"""HT-Bench's reference predictors: models that learn nothing, so a trained model can be judged against them.

They implement `TactileModel` (handtouch.api) and are scored like any model
(handtouch.bench.evaluate); handtouch.bench.verdicts compares against them.
"""

from __future__ import annotations

import torch


class ZerosModel:
    """Predicts no contact everywhere; embeds every map to the same vector
    (retrieval then follows the tie rule: a chance-level reference)."""

    name = "zeros-ref"

    def embed(self, tactile, coverage, hand):
        return torch.ones(tactile.shape[0], 1)

    def inpaint(self, tactile, coverage, mask, rgb, hand):
        return torch.zeros_like(tactile, dtype=torch.float32)

    def rgb_to_tactile(self, rgb, coverage, hand):
        return torch.zeros_like(coverage, dtype=torch.float32)

    def predict_next(self, rgb_window, tactile_window, coverage, hand):
        return torch.zeros_like(coverage, dtype=torch.float32)


class CopyLastModel(ZerosModel):
    """Copies what it is given: the visible map for inpainting (holes stay 0),
    the last tactile frame for prediction; embeds the 8x8-pooled raw map
    (a pixel-space retrieval reference). RGB-to-tactile stays all zeros."""

    name = "copy-last-ref"

    def embed(self, tactile, coverage, hand):
        return torch.nn.functional.avg_pool2d(tactile.float(), 8).flatten(1)

    def inpaint(self, tactile, coverage, mask, rgb, hand):
        return tactile.float() * (1 - mask)

    def predict_next(self, rgb_window, tactile_window, coverage, hand):
        return tactile_window[:, -1].float()
