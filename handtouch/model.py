"""HandTouch: tactile encoder -> (fusion | temporal prediction) -> factorised VQ -> decoder.

Top-level modules (the names stages freeze / unfreeze, config.MODULE_NAMES):
  encoder     tactile encoder (ViT, or a baseline's: config.ARCHITECTURES); input is the map
              with masked pixels zeroed (the paper's single channel), plus the mask itself as
              a second channel with ModelConfig.mask_channel=True
  vq          FactorisedVQ, the shared discrete token space (bypassed without a codebook)
  decoder     -> (B,1,224,224) in [0,1]: attention blocks + conv upsampling (HandTouch), or a
              baseline's conv / linear-patch decoder (decoder.py)
  rgb_proj    frozen-RGB tokens (B,M,C) -> (B,M,D) + positions
  hand_token  learnable left / right token prepended to the tactile tokens
  fusion      stage 2: tactile tokens self-attend and cross-attend to visual tokens
  temporal    stage 3: per-token attention over t_{T-2}, t_{T-1} + time embeddings
  predictor   stage 3: cross-attention from aggregated tokens to v_{T-2..T}
rgb_encoder is always frozen and is not one of them.

The model holds no training logic: each stage's loss is built from the blocks
below in `handtouch.stages` (1 reconstruct, 2 masked reconstruction with RGB,
3 predict t_T). Predictions are zero where coverage is 0.
Ablation switches (ModelConfig): codebook=False bypasses the VQ (continuous latent; the
vit_plain baseline has none either), vision=False gives stages 2-3 the hand token as their
only memory (no RGB). rgb_prior=True fills hidden pixels with the frozen RGB encoder's own
coarse contact map (`rgb_fill`) instead of zeros; rgb_skip=True adds each RGB token to the
tactile token of the same cell before the fusion (measured, not adopted: docs/HANDTOUCH.md, "RGB prior").
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable

import torch
import torch.nn as nn

from htdata.errors import ArgumentError, ConfigError

from .config import MODULE_NAMES, WINDOW, ModelConfig
from .decoder import build_tactile_decoder
from .encoders import build_tactile_encoder, transformer_stack
from .rgb_encoder import RGBEncoder, to_unit_float
from .vq import FactorisedVQ

MODEL_NAMES = {"vit": "handtouch-vit", "cnn": "baseline-cnn", "resnet18": "baseline-resnet18",
               "vqvae": "baseline-vqvae", "vit_plain": "baseline-vit"}


def masked_mse(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Mean squared error over pixels with weight 1 (0/1 weights); 0 when no pixel counts.

    `torch.where` keeps non-finite values at excluded pixels out of the sum and its gradient.
    """
    keep = weight > 0
    zero = torch.zeros((), device=pred.device)
    diff = torch.where(keep, pred.float() - torch.where(keep, target.float(), zero), zero)
    return diff.pow(2).sum() / keep.sum().clamp_min(1).float()


def covered(tactile: torch.Tensor, coverage: torch.Tensor) -> torch.Tensor:
    """The map with every uncovered pixel set to 0 (whatever it held, NaN included)."""
    return torch.where(coverage > 0, tactile.float(), torch.zeros((), device=tactile.device))


class RGBProjector(nn.Module):
    def __init__(self, in_dim: int, num_tokens: int, dim: int):
        super().__init__()
        self.proj = nn.Linear(in_dim, dim)
        self.pos = nn.Parameter(torch.randn(1, num_tokens, dim) * 0.02)
        self.norm = nn.LayerNorm(dim)

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        return self.norm(self.proj(feats.float()) + self.pos)


class CrossAttentionStack(nn.Module):
    """Pre-LN self-attention + cross-attention + MLP layers (nn.TransformerDecoderLayer)."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float, depth: int):
        super().__init__()
        layer = nn.TransformerDecoderLayer(dim, heads, int(dim * mlp_ratio), dropout=0.0,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.layers = nn.TransformerDecoder(layer, depth)
        self.norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor, memory: torch.Tensor) -> torch.Tensor:
        return self.norm(self.layers(x, memory))


class TemporalAggregator(nn.Module):
    """Per-token attention over time: (B,T,N,D) -> (B,N,D), read out at the last step."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float, depth: int, window: int):
        super().__init__()
        self.time = nn.Parameter(torch.randn(window, dim) * 0.02)
        self.blocks = transformer_stack(dim, heads, mlp_ratio, depth)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        b, t, n, d = tokens.shape
        x = (tokens + self.time[:t, None, :]).permute(0, 2, 1, 3).reshape(b * n, t, d)
        return self.blocks(x)[:, -1].reshape(b, n, d)

    def stamp(self, tokens: torch.Tensor) -> torch.Tensor:
        """Add time embeddings to (B,T,M,D) and flatten to (B,T*M,D)."""
        b, t, m, d = tokens.shape
        return (tokens + self.time[:t, None, :]).reshape(b, t * m, d)


def _hand_ids(hand: torch.Tensor) -> torch.Tensor:
    """(B,) or windowed (B,T) hand labels -> (B,) long (the last frame's)."""
    hand = torch.as_tensor(hand)
    if hand.dim() == 2:
        hand = hand[:, -1]
    return hand.long()


class HandTouch(nn.Module):
    def __init__(self, cfg: ModelConfig, rgb_encoder: RGBEncoder):
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.name = MODEL_NAMES[cfg.encoder]
        d = cfg.dim
        self.encoder = build_tactile_encoder(cfg, in_chans=cfg.in_chans)
        self.vq = FactorisedVQ(d, cfg.code_dim, cfg.codebook_size, cfg.vq_beta, cfg.vq_dead_threshold,
                               cfg.vq_usage_decay, cfg.vq_restart_noise)
        self.decoder = build_tactile_decoder(cfg, self.encoder.grid)
        self.rgb_encoder = rgb_encoder
        self.rgb_proj = RGBProjector(rgb_encoder.out_dim, rgb_encoder.num_tokens, d)
        self.hand_token = nn.Embedding(2, d)
        self.fusion = CrossAttentionStack(d, cfg.heads, cfg.mlp_ratio, cfg.fusion_depth)
        self.temporal = TemporalAggregator(d, cfg.heads, cfg.mlp_ratio, cfg.temporal_depth, WINDOW)
        self.predictor = CrossAttentionStack(d, cfg.heads, cfg.mlp_ratio, cfg.predictor_depth)
        self._frozen: set[str] = set()
        if cfg.rgb_prior and cfg.vision and not callable(getattr(rgb_encoder.backbone, "predict", None)):
            raise ConfigError(f"model.rgb_prior needs an RGB encoder with a contact readout (predict, e.g. "
                              f"TactileGridRGB); {rgb_encoder.info.spec!r} has none: set model.rgb_prior=false")

    # ---- freezing by module name -------------------------------------------------
    def _named(self, names: Iterable[str]) -> list[str]:
        names = list(names)
        unknown = sorted(set(names) - set(MODULE_NAMES))
        if unknown:
            raise ArgumentError(f"unknown module names {unknown}; known: {list(MODULE_NAMES)} "
                                "(rgb_encoder is always frozen)")
        return names

    def freeze(self, names: Iterable[str]) -> None:
        for n in self._named(names):
            module = getattr(self, n)
            module.requires_grad_(False)
            module.eval()          # frozen BatchNorm stats and VQ usage / restarts stay put
            self._frozen.add(n)

    def unfreeze(self, names: Iterable[str]) -> None:
        for n in self._named(names):
            module = getattr(self, n)
            module.requires_grad_(True)
            module.train(self.training)
            self._frozen.discard(n)

    def set_trainable(self, names: Iterable[str]) -> None:
        """Train exactly `names`; freeze every other module."""
        names = self._named(names)
        self.freeze([n for n in MODULE_NAMES if n not in names])
        self.unfreeze(names)

    @property
    def frozen(self) -> frozenset[str]:
        return frozenset(self._frozen)

    def train(self, mode: bool = True):
        super().train(mode)
        for n in self._frozen:
            getattr(self, n).eval()
        return self

    # ---- building blocks ----------------------------------------------------------
    def _grad_context(self, name: str):
        return torch.no_grad() if name in self._frozen else contextlib.nullcontext()

    def encode(self, tactile: torch.Tensor, mask: torch.Tensor | None = None,
               fill: torch.Tensor | None = None) -> torch.Tensor:
        """(B,1,224,224) map (+ mask, 1 = hidden) -> tokens (B,N,D); hidden pixels are zeroed, or
        set to `fill` (the RGB prior, `rgb_fill`). The mask is the second input channel unless
        cfg.mask_channel is False."""
        if mask is None:
            mask = torch.zeros_like(tactile)
        x = tactile.float() * (1 - mask)
        if fill is not None:
            x = x + fill.float() * mask
        if self.cfg.mask_channel:
            x = torch.cat([x, mask.float()], dim=1)
        with self._grad_context("encoder"):
            return self.encoder(x)

    def rgb_features(self, rgb: torch.Tensor):
        """The frozen RGB encoder's backbone output for a frame batch (None without vision): pass it to
        `rgb_fill` and `fuse` / `visual_tokens` so one backbone pass serves both (the same numbers as two)."""
        return self.rgb_encoder.features(rgb) if self.cfg.vision else None

    def rgb_fill(self, rgb: torch.Tensor, hand: torch.Tensor, coverage: torch.Tensor,
                 features=None) -> torch.Tensor | None:
        """The frozen RGB encoder's own coarse contact map of the frame, upsampled to the canvas and
        zeroed off the glove: what hidden pixels start from with cfg.rgb_prior (None without it).
        Needs an encoder with a per-hand readout (`predict`, e.g. TactileGridRGB). `features`:
        `rgb_features(rgb)` when the caller has it."""
        if not (self.cfg.rgb_prior and self.cfg.vision):
            return None
        backbone = self.rgb_encoder.backbone      # has `predict`: checked in __init__
        with torch.no_grad():
            feats = backbone(to_unit_float(rgb)) if features is None else features
            coarse = backbone.predict(feats, _hand_ids(hand).to(rgb.device))
            return nn.functional.interpolate(coarse.float(), size=coverage.shape[-2:]) * (coverage > 0)

    def visual_tokens(self, rgb: torch.Tensor, features=None) -> torch.Tensor:
        """(B,3,224,224) uint8 or [0,1] -> (B,M,D); `features`: `rgb_features(rgb)` when the caller has it."""
        return self.rgb_proj(self.rgb_encoder(rgb) if features is None else self.rgb_encoder.tokens(features))

    def _with_hand(self, tokens: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.hand_token(_hand_ids(hand).to(tokens.device))[:, None], tokens], dim=1)

    def fuse(self, tokens: torch.Tensor, rgb: torch.Tensor, hand: torch.Tensor, features=None) -> torch.Tensor:
        """Tactile tokens (B,N,D) + hand token cross-attend to the RGB frame's tokens -> (B,N,D).
        Without vision (ablation) they attend to the hand token alone: same layers, no RGB."""
        if not self.cfg.vision:
            x = self._with_hand(tokens, hand)
            return self.fusion(x, x[:, :1])[:, 1:]
        vis = self.visual_tokens(rgb, features)
        if self.cfg.rgb_skip:
            if vis.shape[1] != tokens.shape[1]:
                raise ConfigError(f"model.rgb_skip needs one RGB token per tactile token: the RGB encoder "
                                  f"gives {vis.shape[1]}, the tactile encoder {tokens.shape[1]}")
            tokens = tokens + vis
        return self.fusion(self._with_hand(tokens, hand), vis)[:, 1:]

    def latent(self, tokens: torch.Tensor):
        """tokens -> (z, indices, losses, stats) of the VQ; without the codebook (ablation) z is
        the tokens themselves, indices 0, no VQ loss and NaN statistics (not applicable)."""
        if self.cfg.quantised:
            return self.vq(tokens)
        # made on the tokens' device: a host tensor copied there each step would stop the host
        zero, nan = tokens.new_zeros((), dtype=torch.float32), tokens.new_full((), float("nan"), dtype=torch.float32)
        indices = torch.zeros(tokens.shape[:2], dtype=torch.long, device=tokens.device)
        return tokens.float(), indices, {"codebook": zero, "commit": zero}, \
            {"perplexity": nan, "usage": nan, "restarts": zero}

    def quantise_decode(self, tokens: torch.Tensor, coverage: torch.Tensor):
        """tokens -> VQ -> map * coverage; returns (map, indices, vq losses, vq stats)."""
        z, indices, losses, stats = self.latent(tokens)
        return self.decoder(z) * coverage, indices, losses, stats

    def _inpaint(self, tactile, coverage, mask, rgb, hand, features=None):
        feats = self.rgb_features(rgb) if features is None else features
        tokens = self.encode(tactile, mask, self.rgb_fill(rgb, hand, coverage, feats))
        return self.quantise_decode(self.fuse(tokens, rgb, hand, feats), coverage)

    def predicted_tokens(self, rgb_window, past_tokens, hand):
        """Encoded past frames (B,T-1,N,D) + RGB v_{T-2..T} -> predicted t_T tokens (B,N,D), before VQ."""
        past = self.temporal(past_tokens)
        if not self.cfg.vision:      # ablation: the hand token is the only memory
            x = self._with_hand(past, hand)
            return self.predictor(x, x[:, :1])[:, 1:]
        b, tv = rgb_window.shape[:2]
        vis = self.visual_tokens(rgb_window.reshape(b * tv, *rgb_window.shape[2:]))
        vis = self.temporal.stamp(vis.reshape(b, tv, *vis.shape[1:]))
        return self.predictor(self._with_hand(past, hand), vis)[:, 1:]

    def encode_frames(self, frames: torch.Tensor) -> torch.Tensor:
        """(B,T,1,H,W) -> tokens (B,T,N,D) in one encoder call."""
        b, t = frames.shape[:2]
        tokens = self.encode(frames.reshape(b * t, *frames.shape[2:]))
        return tokens.reshape(b, t, *tokens.shape[1:])

    def _predict_next(self, rgb_window, tactile_window, coverage, hand):
        pred = self.predicted_tokens(rgb_window, self.encode_frames(tactile_window), hand)
        return self.quantise_decode(pred, coverage)

    # ---- TactileModel API ---------------------------------------------------------
    def embed(self, tactile, coverage, hand) -> torch.Tensor:
        """(B,D): mean of the quantised tokens of the (unmasked) map."""
        z, _, _, _ = self.latent(self.encode(covered(tactile, coverage)))
        return z.mean(dim=1)

    def reconstruct(self, tactile, coverage) -> torch.Tensor:
        return self.quantise_decode(self.encode(covered(tactile, coverage)), coverage)[0]

    def inpaint(self, tactile, coverage, mask, rgb, hand) -> torch.Tensor:
        return self._inpaint(covered(tactile, coverage), coverage, mask, rgb, hand)[0]

    def rgb_to_tactile(self, rgb, coverage, hand, features=None) -> torch.Tensor:
        """`features`: `rgb_features(rgb)` when the caller has them (the held-out gate scores each frame's
        RGB under three pairings: one backbone pass per frame, not three)."""
        blank = torch.zeros_like(coverage, dtype=torch.float32)
        return self._inpaint(blank, coverage, torch.ones_like(blank), rgb, hand, features)[0]

    def predict_next(self, rgb_window, tactile_window, coverage, hand) -> torch.Tensor:
        past = covered(tactile_window, coverage[:, None])
        return self._predict_next(rgb_window, past, coverage, hand)[0]
