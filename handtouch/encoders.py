"""Tactile encoders with one interface: (B, C, 224, 224) -> tokens (B, N, D).

ViTEncoder is HandTouch's (and the plain-ViT baseline's); CNNEncoder, ResNet18Encoder and
VQVAEEncoder are the conv baselines (tokens = final feature map flattened and projected to D;
widths from ModelConfig.cnn_widths / resnet_widths / vqvae_widths). Each exposes
`.grid` (tokens per side) so the decoder knows how far to upsample.
"""

from __future__ import annotations

import torch
import torch.nn as nn

from htdata.format.canvas import CANVAS

from .config import CNN_GRID, RESNET_GRID, ModelConfig


def transformer_stack(dim: int, heads: int, mlp_ratio: float, depth: int) -> nn.TransformerEncoder:
    """Pre-LN ViT blocks in plain torch. Nested tensors are off: torch cannot use them with
    norm_first layers and would only warn that it ignores the setting."""
    layer = nn.TransformerEncoderLayer(dim, heads, int(dim * mlp_ratio), dropout=0.0,
                                       activation="gelu", batch_first=True, norm_first=True)
    return nn.TransformerEncoder(layer, depth, enable_nested_tensor=False)


class ViTEncoder(nn.Module):
    def __init__(self, in_chans: int, patch: int, dim: int, depth: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.grid = CANVAS // patch
        self.patch_embed = nn.Conv2d(in_chans, dim, kernel_size=patch, stride=patch)
        self.pos = nn.Parameter(torch.randn(1, self.grid * self.grid, dim) * 0.02)
        self.blocks = transformer_stack(dim, heads, mlp_ratio, depth)
        self.norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        tokens = self.patch_embed(x).flatten(2).transpose(1, 2) + self.pos
        return self.norm(self.blocks(tokens))


class _FeatureMapTokens(nn.Module):
    """Flatten a (B,C,g,g) feature map into tokens and project C -> D, plus positions."""

    def __init__(self, channels: int, dim: int, grid: int):
        super().__init__()
        self.proj = nn.Linear(channels, dim)
        self.pos = nn.Parameter(torch.randn(1, grid * grid, dim) * 0.02)
        self.norm = nn.LayerNorm(dim)

    def forward(self, fmap: torch.Tensor) -> torch.Tensor:
        return self.norm(self.proj(fmap.flatten(2).transpose(1, 2)) + self.pos)


class CNNEncoder(nn.Module):
    """Plain conv stack, stride 16 (224 -> 14): a stride-4 patchify stem, then stride-2 stages.

    The stem works on 4x4 patches like the ViT's patch embedding: 3x3 convs at full or
    half resolution cost ~6x the whole ViT step on 2 CPU cores (562 s for a smoke run).
    widths = (stem, stage 1, stage 2); each is followed by a 3x3 conv at the same size.
    """

    def __init__(self, in_chans: int, dim: int, widths: tuple[int, ...] = (32, 64, 128)):
        super().__init__()
        if len(widths) != 3:
            raise ValueError(f"CNNEncoder needs 3 widths (stem + 2 stride-2 stages), got {list(widths)}")

        def conv(c_in: int, c_out: int, k: int, stride: int) -> list[nn.Module]:
            # 3x3 convs are padded (same size / exact halving); the 4x4 stride-4 stem tiles exactly
            return [nn.Conv2d(c_in, c_out, k, stride=stride, padding=1 if k == 3 else 0),
                    nn.GroupNorm(8, c_out), nn.GELU()]

        layers = conv(in_chans, widths[0], 4, 4) + conv(widths[0], widths[0], 3, 1)
        c = widths[0]
        for w in widths[1:]:
            layers += conv(c, w, 3, 2) + conv(w, w, 3, 1)
            c = w
        self.features = nn.Sequential(*layers)
        self.grid = CNN_GRID
        self.tokens = _FeatureMapTokens(c, dim, self.grid)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.tokens(self.features(x))


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 convs + identity (or 1x1 strided) shortcut."""

    def __init__(self, c_in: int, c_out: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.shortcut = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride=stride, bias=False),
                                          nn.BatchNorm2d(c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + self.shortcut(x))


class ResNet18Encoder(nn.Module):
    """ResNet-18 layout (stride-4 stem + 4 stages x 2 basic blocks), stride 32 -> 7x7 tokens.

    widths (64, 128, 256, 512) are torchvision's (1.8 GMAC per map); the smoke config
    narrows them (configs/smoke.toml) so the baseline costs about what the ViT costs.
    """

    def __init__(self, in_chans: int, dim: int, widths: tuple[int, ...] = (64, 128, 256, 512)):
        super().__init__()
        if len(widths) != 4:
            raise ValueError(f"ResNet18Encoder needs 4 stage widths, got {list(widths)}")
        self.stem = nn.Sequential(
            nn.Conv2d(in_chans, widths[0], 7, stride=2, padding=3, bias=False),
            nn.BatchNorm2d(widths[0]), nn.ReLU(inplace=True), nn.MaxPool2d(3, stride=2, padding=1))
        stages, c = [], widths[0]
        for i, w in enumerate(widths):
            stride = 1 if i == 0 else 2
            stages += [BasicBlock(c, w, stride), BasicBlock(w, w, 1)]
            c = w
        self.stages = nn.Sequential(*stages)
        self.grid = RESNET_GRID
        self.tokens = _FeatureMapTokens(c, dim, self.grid)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.tokens(self.stages(self.stem(x)))


class ResidualStack(nn.Module):
    """VQ-VAE residual blocks (van den Oord et al. 2017): x + conv1x1(ReLU(conv3x3(ReLU(x)))),
    `depth` times, then a ReLU. Works on (B,C,g,g) maps; no normalisation, as in the paper."""

    def __init__(self, channels: int, hidden: int, depth: int):
        super().__init__()
        self.blocks = nn.ModuleList(
            nn.Sequential(nn.ReLU(), nn.Conv2d(channels, hidden, 3, padding=1), nn.ReLU(),
                          nn.Conv2d(hidden, channels, 1)) for _ in range(depth))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for block in self.blocks:
            x = x + block(x)
        return torch.relu(x)


class VQVAEEncoder(nn.Module):
    """The encoder of a conv VQ-VAE, stride 16 (224 -> 14): strided 4x4 convs (a stride-4 stem,
    then two stride-2 stages, widths = vqvae_widths), a 3x3 conv and two residual blocks.

    The original downsamples with stride-2 4x4 convs from full resolution; the stride-4 stem is the
    CNN baseline's CPU concession (a full-resolution conv costs several ViT steps). Tokens get the
    same learned positions + LayerNorm as the other conv encoders (_FeatureMapTokens), so the
    shared stage-2/3 attention can tell places apart.
    """

    def __init__(self, in_chans: int, dim: int, widths: tuple[int, ...] = (32, 64, 128), res_depth: int = 2):
        super().__init__()
        if len(widths) != 3:
            raise ValueError(f"VQVAEEncoder needs 3 widths (stem + 2 stride-2 stages), got {list(widths)}")
        layers: list[nn.Module] = [nn.Conv2d(in_chans, widths[0], 4, stride=4), nn.ReLU()]
        c = widths[0]
        for w in widths[1:]:
            layers += [nn.Conv2d(c, w, 4, stride=2, padding=1), nn.ReLU()]
            c = w
        layers += [nn.Conv2d(c, c, 3, padding=1), ResidualStack(c, max(c // 2, 8), res_depth)]
        self.features = nn.Sequential(*layers)
        self.grid = CNN_GRID
        self.tokens = _FeatureMapTokens(c, dim, self.grid)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.tokens(self.features(x))


def build_tactile_encoder(cfg: ModelConfig, in_chans: int) -> nn.Module:
    if cfg.encoder in ("vit", "vit_plain"):
        return ViTEncoder(in_chans, cfg.patch, cfg.dim, cfg.depth, cfg.heads, cfg.mlp_ratio)
    if cfg.encoder == "cnn":
        return CNNEncoder(in_chans, cfg.dim, tuple(cfg.cnn_widths))
    if cfg.encoder == "resnet18":
        return ResNet18Encoder(in_chans, cfg.dim, tuple(cfg.resnet_widths))
    if cfg.encoder == "vqvae":
        return VQVAEEncoder(in_chans, cfg.dim, tuple(cfg.vqvae_widths))
    raise ValueError(f"unknown tactile encoder {cfg.encoder!r}")
