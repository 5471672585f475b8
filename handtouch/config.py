"""Plain dataclass configs for the HandTouch model and trainer, loaded from TOML.

Every config has `validate()`; `load_train_config` rejects unknown keys so a
typo in a TOML file is an error, not a silently ignored setting.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from htdata.errors import ConfigError
from htdata.format.canvas import CANVAS
from htdata.settings import apply_settings, parse_setting

# model.encoder -> (tactile decoder, quantised latent). "vit" is HandTouch; the others are the
# paper's four encoder baselines (docs/HANDTOUCH.md "Baselines"): cnn and resnet18 swap the tactile encoder
# only; vqvae is a conv VQ-VAE tokeniser (conv encoder -> the same VQ -> conv decoder, no attention
# in the autoencoder); vit_plain is a plain ViT regressor (the ViT encoder, no codebook, a linear
# per-patch pixel head). Stages 2-3 keep the same fusion / temporal / predictor for every one, so a
# row measures the tokeniser, not a different way of using RGB.
ARCHITECTURES = {
    "vit": ("attention", True),
    "cnn": ("attention", True),
    "resnet18": ("attention", True),
    "vqvae": ("conv", True),
    "vit_plain": ("linear", False),
}
ENCODERS = tuple(ARCHITECTURES)
# Frames per stage-3 window (t_{T-2..T}): the temporal model's length, the trainer's and
# HT-Bench's window datasets.
WINDOW = 3
# Top-level modules of HandTouch that a stage may train (see model.py).
MODULE_NAMES = ("encoder", "vq", "decoder", "rgb_proj", "hand_token", "fusion", "temporal", "predictor")
# Token grid side of the baselines' encoders (stride 16 CNN, stride 32 ResNet-18).
CNN_GRID = 14
RESNET_GRID = 7


@dataclass
class ModelConfig:
    encoder: str = "vit"          # vit (HandTouch) | cnn | resnet18 | vqvae | vit_plain (baselines, ARCHITECTURES)
    patch: int = 16               # ViT patch size (vit, vit_plain; 224 / patch must be a power-of-two divisor)
    dim: int = 384                # token width D
    depth: int = 8                # ViT encoder depth
    heads: int = 6
    mlp_ratio: float = 4.0
    code_dim: int = 32            # factorised VQ: d
    codebook_size: int = 2048     # K
    vq_beta: float = 0.25
    vq_dead_threshold: float = 1.0   # tau on the usage EMA (expected uses per step)
    vq_usage_decay: float = 0.99
    vq_restart_noise: float = 0.01
    decoder_depth: int = 2        # attention blocks before conv upsampling
    decoder_channels: int = 64    # channels after the first upsampling step (halved per step, >= 8)
    fusion_depth: int = 2         # stage 2 cross-attention layers
    temporal_depth: int = 1       # stage 3 per-token attention over time
    predictor_depth: int = 2      # stage 3 cross-attention layers
    cnn_widths: list[int] = field(default_factory=lambda: [32, 64, 128])   # baseline CNN: stem, 2 stages
    resnet_widths: list[int] = field(default_factory=lambda: [64, 128, 256, 512])  # baseline ResNet-18 stages
    vqvae_widths: list[int] = field(default_factory=lambda: [32, 64, 128])  # baseline VQ-VAE: stem, 2 stages
    # Encoder input: False = the paper's 1 channel (the map only: a hidden pixel looks like "no
    # contact"), True = 2 channels (+ the hidden-pixel mask). The paper's, because the mask lost:
    # the smoke with 1 vs 2 channels, test, reconstruction 0.030 vs 0.042, inpainting F 0.038 vs
    # 0.050, H 0.055 vs 0.055, prediction 0.036 vs 0.045, Hit@1 0.305 vs 0.335; `make compare`,
    # 2 seeds, row "2-channel input" (docs/HANDTOUCH.md, "Encoder input").
    mask_channel: bool = False
    # Ablations of the paper's comparison; both True is HandTouch.
    codebook: bool = True         # False = "w/o codebook": continuous latent, the VQ is bypassed
    vision: bool = True           # False = "w/o vision": stages 2-3 attend to the hand token, never to RGB
    # RGB prior: hidden pixels start from the frozen RGB encoder's own coarse contact map of the
    # frame (upsampled; needs a readout, e.g. TactileGridRGB) instead of 0, in stage 2 and in
    # inpainting / RGB-to-tactile alike (with mask_channel the mask still marks them). Off = the
    # paper's zeros.
    # Why: with zeros, 100 stage-2 steps never learned to read the frame (docs/HANDTOUCH.md, "RGB prior").
    rgb_prior: bool = False
    # Measured, not adopted (docs/HANDTOUCH.md, "RGB prior"): add each RGB token to the tactile token of the
    # same canvas cell before the fusion (needs one RGB token per tactile token).
    rgb_skip: bool = False

    @property
    def grid(self) -> int:
        """Tokens per side produced by the tactile encoder."""
        if self.encoder in ("vit", "vit_plain"):
            return CANVAS // self.patch
        return RESNET_GRID if self.encoder == "resnet18" else CNN_GRID

    @property
    def decoder_kind(self) -> str:
        """attention | conv | linear (ARCHITECTURES)."""
        return ARCHITECTURES[self.encoder][0]

    @property
    def quantised(self) -> bool:
        """Whether the latent goes through the VQ: the architecture has a codebook and the
        "w/o codebook" ablation is off."""
        return ARCHITECTURES[self.encoder][1] and self.codebook

    @property
    def in_chans(self) -> int:
        return 2 if self.mask_channel else 1

    @property
    def num_tokens(self) -> int:
        return self.grid * self.grid

    def validate(self) -> None:
        if self.encoder not in ENCODERS:
            raise ConfigError(f"model.encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.encoder in ("vit", "vit_plain"):
            if self.patch <= 0 or CANVAS % self.patch:
                raise ConfigError(f"model.patch={self.patch} must divide {CANVAS}")
        up = CANVAS // self.grid
        if up & (up - 1):
            raise ConfigError(f"model.patch={self.patch}: upsampling factor {up} must be a power of two")
        for name in ("dim", "depth", "heads", "code_dim", "codebook_size", "decoder_channels"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"model.{name} must be > 0, got {getattr(self, name)}")
        for name in ("decoder_depth", "fusion_depth", "temporal_depth", "predictor_depth"):
            if getattr(self, name) < 1:
                raise ConfigError(f"model.{name} must be >= 1, got {getattr(self, name)}")
        if self.dim % self.heads:
            raise ConfigError(f"model.dim={self.dim} must be divisible by model.heads={self.heads}")
        if len(self.cnn_widths) != 3 or any(int(w) <= 0 or int(w) % 8 for w in self.cnn_widths):
            raise ConfigError(f"model.cnn_widths must be 3 positive multiples of 8 (GroupNorm(8)), "
                              f"got {self.cnn_widths}")
        if len(self.vqvae_widths) != 3 or any(int(w) <= 0 or int(w) % 8 for w in self.vqvae_widths):
            raise ConfigError(f"model.vqvae_widths must be 3 positive multiples of 8 (GroupNorm(8)), "
                              f"got {self.vqvae_widths}")
        if len(self.resnet_widths) != 4 or any(int(w) <= 0 for w in self.resnet_widths):
            raise ConfigError(f"model.resnet_widths must be 4 positive widths, got {self.resnet_widths}")
        if self.mlp_ratio <= 0:
            raise ConfigError("model.mlp_ratio must be > 0")
        if self.vq_beta < 0 or self.vq_dead_threshold < 0 or self.vq_restart_noise < 0:
            raise ConfigError("model.vq_beta, vq_dead_threshold, vq_restart_noise must be >= 0")
        for name in ("codebook", "vision", "mask_channel", "rgb_prior", "rgb_skip"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"model.{name} must be true/false, got {getattr(self, name)!r}")
        if not 0.0 < self.vq_usage_decay < 1.0:
            raise ConfigError(f"model.vq_usage_decay must be in (0,1), got {self.vq_usage_decay}")


@dataclass
class StageConfig:
    steps: int = 100
    lr: float = 3e-4
    weight_decay: float = 0.05
    warmup_steps: int = 10
    grad_clip: float = 1.0
    trainable: list[str] = field(default_factory=list)   # top-level module names (MODULE_NAMES)

    def validate(self, where: str) -> None:
        if self.steps < 0:
            raise ConfigError(f"{where}.steps must be >= 0")
        if self.lr <= 0 or self.weight_decay < 0 or self.warmup_steps < 0 or self.grad_clip <= 0:
            raise ConfigError(f"{where}: lr and grad_clip must be > 0, weight_decay/warmup_steps >= 0")
        if not self.trainable:
            raise ConfigError(f"{where}.trainable is empty: name the modules this stage trains")
        unknown = sorted(set(self.trainable) - set(MODULE_NAMES))
        if unknown:
            raise ConfigError(f"{where}.trainable has unknown modules {unknown}; known: {list(MODULE_NAMES)}")


@dataclass
class MaskingConfig:
    """Stage-2 curriculum: P_full(g) = p_min + (p_max - p_min) / (1 + exp(-12 (g - 0.5)))."""
    p_min: float = 0.1
    p_max: float = 0.9
    max_parts: int = 2            # a regional mask hides 1..max_parts anatomical parts
    # False = the paper's "w/o drop" ablation: no curriculum, P_full stays at its midpoint
    # (p_min + p_max) / 2 for the whole stage (the same average share of complete masks).
    curriculum: bool = True

    def validate(self) -> None:
        if not 0.0 <= self.p_min <= self.p_max <= 1.0:
            raise ConfigError(f"masking: need 0 <= p_min <= p_max <= 1, got {self.p_min}, {self.p_max}")
        if not isinstance(self.curriculum, bool):
            raise ConfigError(f"masking.curriculum must be true/false, got {self.curriculum!r}")
        if not 1 <= self.max_parts <= 6:
            raise ConfigError(f"masking.max_parts must be in 1..6, got {self.max_parts}")


@dataclass
class LossConfig:
    lambda_vis: float = 0.5       # stage 2, visible covered pixels
    lambda_mask: float = 1.0      # stage 2, masked covered pixels (must exceed lambda_vis)
    vq_weight: float = 1.0        # weight of the VQ codebook + commitment terms
    # Stage-2 reconstruction replay: the whole map through encoder -> VQ -> decoder, as in
    # stage 1, next to the masked terms (stage 2 fine-tunes the shared encoder, VQ and decoder).
    lambda_replay: float = 1.0
    # Stage 3 is the paper's |t_T - t^_T|^2 by default. Opt-in additions (docs/HANDTOUCH.md, "Stage-3
    # loss"): stage3_replay x the reconstruction of t_T through encoder -> VQ -> decoder, and
    # stage3_vq = add vq_weight x the VQ codebook + commitment terms of the predicted tokens.
    stage3_replay: float = 0.0
    stage3_vq: bool = False

    def validate(self) -> None:
        if self.lambda_vis < 0 or self.vq_weight < 0 or self.lambda_replay < 0 or self.stage3_replay < 0:
            raise ConfigError("loss.lambda_vis, loss.vq_weight, loss.lambda_replay and loss.stage3_replay "
                              "must be >= 0")
        if not isinstance(self.stage3_vq, bool):
            raise ConfigError(f"loss.stage3_vq must be true/false, got {self.stage3_vq!r}")
        if not self.lambda_mask > self.lambda_vis:
            raise ConfigError(f"loss.lambda_mask ({self.lambda_mask}) must exceed lambda_vis ({self.lambda_vis})")


def _default_stage(trainable: list[str]) -> StageConfig:
    return StageConfig(trainable=list(trainable))


@dataclass
class TrainConfig:
    data_root: str                # committed htdata dataset (local path or fsspec URL)
    out_dir: str                  # checkpoints, log.jsonl, metrics.json
    rgb_encoder: str              # "random:SEED" or a path to a .pt2 / .pt file (see rgb_encoder.py)
    split: str = ""               # split name under DATASET/splits/; "" = whole dataset, no held-out part
    train_part: str = "train"
    eval_part: str = "test"
    seed: int = 0
    device: str = "auto"          # auto | cpu | cuda | cuda:N
    bf16: bool = False
    workers: int = 2
    threads: int = 0              # torch intra-op threads of the training process; 0 = torch's default
    prefetch: int = 2             # batches each DataLoader worker keeps ready (prefetch_factor)
    compile: bool = False         # torch.compile the step's loss module (measured: docs/HANDTOUCH.md, "Feeding a GPU")
    batch_size: int = 32
    eval_batch_size: int = 16
    log_every: int = 10
    checkpoint_every: int = 100
    stages: list[int] = field(default_factory=lambda: [1, 2, 3])
    model: ModelConfig = field(default_factory=ModelConfig)
    masking: MaskingConfig = field(default_factory=MaskingConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    stage1: StageConfig = field(default_factory=lambda: _default_stage(["encoder", "vq", "decoder"]))
    stage2: StageConfig = field(default_factory=lambda: _default_stage(
        ["encoder", "vq", "decoder", "rgb_proj", "hand_token", "fusion"]))
    stage3: StageConfig = field(default_factory=lambda: _default_stage(
        ["temporal", "predictor", "rgb_proj", "hand_token", "vq", "decoder"]))

    def stage(self, n: int) -> StageConfig:
        return getattr(self, f"stage{n}")

    def validate(self) -> None:
        if not self.data_root:
            raise ConfigError("data_root is empty")
        if not self.out_dir:
            raise ConfigError("out_dir is empty")
        if not self.rgb_encoder:
            raise ConfigError("rgb_encoder is empty: use 'random:SEED' (smoke) or a local .pt2/.pt file")
        if self.device != "auto" and not (self.device == "cpu" or self.device.startswith("cuda")):
            raise ConfigError(f"device must be auto, cpu or cuda[:N], got {self.device!r}")
        if self.workers < 0 or self.threads < 0 or self.batch_size < 1 or self.eval_batch_size < 1 or self.prefetch < 1:
            raise ConfigError("workers >= 0, threads >= 0, batch_size >= 1, eval_batch_size >= 1, prefetch >= 1 required")
        if self.log_every < 1 or self.checkpoint_every < 1:
            raise ConfigError("log_every and checkpoint_every must be >= 1")
        if not self.stages or any(s not in (1, 2, 3) for s in self.stages) or self.stages != sorted(set(self.stages)):
            raise ConfigError(f"stages must be an increasing subset of [1, 2, 3], got {self.stages}")
        self.model.validate()
        self.masking.validate()
        self.loss.validate()
        for n in (1, 2, 3):
            self.stage(n).validate(f"stage{n}")
        self.check_codebook_load(world_size=1)

    def check_codebook_load(self, world_size: int) -> None:
        """Refuse batches too small for the codebook: if the expected uses per code per
        step are below 2 x the dead threshold, healthy codes look dead and get restarted
        every step (the usage EMA of a code used ~once per step hovers around the threshold)."""
        m = self.model
        if not m.quantised:      # no codebook in the latent: nothing to starve
            return
        per_code = self.batch_size * world_size * m.num_tokens / m.codebook_size
        if per_code < 2 * m.vq_dead_threshold:
            raise ConfigError(
                f"batch_size={self.batch_size} x world {world_size} x {m.num_tokens} tokens / "
                f"codebook_size={m.codebook_size} = {per_code:.2f} uses per code per step, below "
                f"2 x vq_dead_threshold={m.vq_dead_threshold}: lower the codebook size or threshold")


def _build(cls, data: dict[str, Any], where: str):
    """Build dataclass `cls` from a dict, recursing into nested dataclasses; unknown keys fail."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where or '<root>'}: expected a table, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where or '<root>'}: unknown keys {unknown}; known: {sorted(fields)}")
    kwargs = {}
    for name, value in data.items():
        ftype = fields[name].type
        nested = _NESTED.get(ftype) if isinstance(ftype, str) else None
        kwargs[name] = _build(nested, value, f"{where}.{name}" if where else name) if nested else value
    try:
        return cls(**kwargs)
    except TypeError as e:   # missing required keys
        raise ConfigError(f"{where or '<root>'}: {e}") from None


_NESTED = {"ModelConfig": ModelConfig, "StageConfig": StageConfig, "MaskingConfig": MaskingConfig,
           "LossConfig": LossConfig}


def parse_override(text: str) -> tuple[list[str], Any]:
    """'model.dim=64' -> (['model', 'dim'], 64): htdata's one `--set` parser (htdata/settings.py)."""
    key, value = parse_setting(text)
    return key.split("."), value


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """`data` with `--set` overrides written in (htdata/settings.py)."""
    return apply_settings(data, list(overrides))


def train_config_from_dict(data: dict) -> TrainConfig:
    cfg = _build(TrainConfig, data, "")
    cfg.validate()
    return cfg


def load_train_config(path: str | Path, overrides: list[str] = ()) -> TrainConfig:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    with path.open("rb") as f:
        try:
            data = tomllib.load(f)
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{path}: {e}") from None
    try:
        return train_config_from_dict(apply_overrides(data, list(overrides)))
    except ValueError as e:
        raise ConfigError(f"{path}: {e}") from None


def model_config_from_dict(data: dict) -> ModelConfig:
    cfg = _build(ModelConfig, data, "model")
    cfg.validate()
    return cfg
