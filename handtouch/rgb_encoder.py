"""Frozen RGB encoder, chosen by a spec string; never downloads, never falls back.

Specs:
  "random:SEED"      a seeded random small conv encoder, explicitly for smoke runs
  "PATH.pt2"         a torch.export archive: torch.export.load(PATH).module(); export it
                     with a dynamic batch dimension (dynamic_shapes={0: Dim("batch")})
  "PATH.pt"          {"arch": NAME, "state_dict": ..., optional "config": {kwargs}} for an
                     architecture in ARCHS (handtouch.rgb_pretrain writes "tactile_grid" files)

The encoder receives float32 (B,3,224,224) in [0,1] (any normalisation the
weights expect must live inside the exported module / architecture) and
returns tokens (B,M,C), a feature map (B,C,h,w) or a vector (B,C);
`RGBEncoder` turns all three into tokens (B,M,C).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn as nn

from htdata.errors import ConfigError
from htdata.format.canvas import CANVAS
from htdata.store.fsutil import sha256_file

log = logging.getLogger("handtouch.rgb_encoder")


class SmallConvRGB(nn.Module):
    """Five conv stages (224 -> 7); ImageNet-style normalisation inside."""

    def __init__(self, width: int = 64):
        super().__init__()
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1))
        layers, c = [], 3
        for w in (16, 32, width, width, width):
            layers += [nn.Conv2d(c, w, 3, stride=2, padding=1), nn.GELU()]
            c = w
        self.features = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features((x - self.mean) / self.std)


class TactileGridRGB(nn.Module):
    """A small RGB encoder whose output lives on the tactile canvas: (B,C,grid,grid) features,
    one cell per ViT patch of the tactile map, read out per hand by `readout` (C -> 2 maps).

    Trained by handtouch.rgb_pretrain to predict each hand's coarse contact map from the
    frame. The image is average-pooled to `size` first (the sample scenes need no more
    detail; ~7x cheaper than SmallConvRGB at 224); conv features are pooled over the image
    (mean and max), so what the hand does counts, not where it is in the frame.
    """

    def __init__(self, size: int = 56, width: int = 64, channels: int = 16, grid: int = 14, hidden: int = 128):
        super().__init__()
        self.config = {"size": size, "width": width, "channels": channels, "grid": grid, "hidden": hidden}
        self.size, self.channels, self.grid = size, channels, grid
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1))
        layers, c = [], 3
        for i, w in enumerate((width // 2, width, width, width)):      # size / 8 per side, e.g. 56 -> 7
            layers += [nn.Conv2d(c, w, 3, stride=2 if i < 3 else 1, padding=1), nn.GELU()]
            c = w
        self.features = nn.Sequential(*layers)
        self.to_grid = nn.Sequential(nn.Linear(2 * c, hidden), nn.LayerNorm(hidden), nn.GELU(),
                                     nn.Linear(hidden, channels * grid * grid))
        self.readout = nn.Conv2d(channels, 2, 1)   # per hand (htdata.read.keys.HAND_IDS order)

    def pooled(self, x: torch.Tensor) -> torch.Tensor:
        """(B,3,H,W) float [0,1] -> (B,3,size,size) (the input the pretraining caches)."""
        return x if x.shape[-1] == self.size else nn.functional.adaptive_avg_pool2d(x, self.size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = self.features((self.pooled(x) - self.mean) / self.std)
        z = torch.cat([z.mean((2, 3)), z.amax((2, 3))], 1)
        return self.to_grid(z).view(-1, self.channels, self.grid, self.grid)

    def predict(self, features: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
        """(B,C,grid,grid) features + (B,) hand ids -> (B,1,grid,grid) coarse contact map."""
        maps = self.readout(features)
        return maps.gather(1, hand.long().view(-1, 1, 1, 1).expand(-1, 1, *maps.shape[2:]))


ARCHS = {"small_conv": SmallConvRGB, "tactile_grid": TactileGridRGB}


@dataclass(frozen=True)
class RGBEncoderInfo:
    spec: str
    kind: str          # random | export | state_dict
    sha256: str        # of the file; "" for random encoders


def to_unit_float(rgb: torch.Tensor) -> torch.Tensor:
    """uint8 0..255 or float [0,1] -> float32 [0,1]."""
    if rgb.dtype == torch.uint8:
        return rgb.float() / 255.0
    return rgb.float()


class RGBEncoder(nn.Module):
    """Wraps a frozen backbone: always eval, no grad, output as tokens (B,M,C)."""

    def __init__(self, backbone: nn.Module, info: RGBEncoderInfo):
        super().__init__()
        self.backbone = backbone
        self.info = info
        for p in self.backbone.parameters():
            p.requires_grad_(False)
        self.train(False)
        with torch.no_grad():
            probe = self(torch.zeros(1, 3, CANVAS, CANVAS, dtype=torch.uint8))
        self.num_tokens, self.out_dim = probe.shape[1], probe.shape[2]

    def train(self, mode: bool = True):
        """Frozen: never leaves eval mode. An exported module keeps the mode it was traced in
        (its train()/eval() raise), so it is left alone."""
        self.training = False
        if self.info.kind != "export":
            self.backbone.eval()
        return self

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.tokens(self.features(rgb))

    def features(self, rgb: torch.Tensor):
        """The frozen backbone's raw output for a frame batch: computed once, it feeds both the tokens
        (`tokens`) and a readout's coarse map (TactileGridRGB.predict), which took a backbone pass each."""
        with torch.no_grad():
            return self.backbone(to_unit_float(rgb))

    def tokens(self, out) -> torch.Tensor:
        """`features` output -> tokens (B,M,C)."""
        if isinstance(out, (tuple, list)):
            out = out[0]
        if out.dim() == 4:
            return out.flatten(2).transpose(1, 2)
        if out.dim() == 2:
            return out[:, None, :]
        if out.dim() == 3:
            return out
        raise ValueError(f"RGB encoder {self.info.spec!r} returned shape {tuple(out.shape)}; "
                         "expected (B,M,C), (B,C,h,w) or (B,C)")


def _random_backbone(seed: int) -> nn.Module:
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return SmallConvRGB()


def load_rgb_encoder(spec: str) -> RGBEncoder:
    """Build the frozen RGB encoder named by `spec` (see module docstring)."""
    if spec.startswith("random:"):
        try:
            seed = int(spec.split(":", 1)[1])
        except ValueError:
            raise ConfigError(f"rgb encoder spec {spec!r}: expected random:SEED with an integer seed") from None
        log.warning("RGB encoder: RANDOM small conv (seed %d) - smoke runs only, not a pretrained model", seed)
        return RGBEncoder(_random_backbone(seed), RGBEncoderInfo(spec, "random", ""))
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"RGB encoder file not found: {path}")
    digest = sha256_file(path)
    if path.suffix == ".pt2":
        backbone = torch.export.load(str(path)).module()
        info = RGBEncoderInfo(spec, "export", digest)
    elif path.suffix == ".pt":
        blob = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(blob, dict) or "arch" not in blob or "state_dict" not in blob:
            raise ConfigError(f"{path}: expected a dict with 'arch' and 'state_dict'")
        if blob["arch"] not in ARCHS:
            raise ConfigError(f"{path}: unknown arch {blob['arch']!r}; known: {sorted(ARCHS)}")
        try:
            backbone = ARCHS[blob["arch"]](**blob.get("config", {}))
        except TypeError as e:
            raise ConfigError(f"{path}: bad config for arch {blob['arch']!r}: {e}") from None
        backbone.load_state_dict(blob["state_dict"])
        info = RGBEncoderInfo(spec, "state_dict", digest)
    else:
        raise ConfigError(f"{path}: RGB encoder files must be .pt2 (torch.export) or .pt (state dict)")
    log.info("RGB encoder: %s (%s) sha256=%s", path, info.kind, digest)
    return RGBEncoder(backbone, info)


def model_rgb_features(model, rgb: torch.Tensor, batch_size: int) -> torch.Tensor | None:
    """A model's frozen RGB backbone output for every frame of `rgb`, once, in batches (a model with
    `rgb_features` returning one tensor, as HandTouch's does: pass its rows as `rgb_to_tactile(...,
    features=)`), or None: the model then encodes each frame it is fed. Scoring a frame's RGB under
    several pairings then costs one backbone pass per frame, not one per pairing."""
    if not callable(getattr(model, "rgb_features", None)) or len(rgb) == 0:
        return None
    parts = [model.rgb_features(rgb[s:s + batch_size]) for s in range(0, len(rgb), batch_size)]
    return torch.cat(parts) if all(isinstance(p, torch.Tensor) for p in parts) else None
