"""The training stages, one object each: what it reads, how it prepares a batch, its loss,
and which of HandTouch's modules it trains (by name, config.MODULE_NAMES; the rest is frozen).

  1 Reconstruction        frames   map -> encoder -> VQ -> decoder
  2 MaskedFusion          frames   masked map + RGB frame -> fusion -> VQ -> decoder
  3 NextFramePrediction   windows  t_{T-2..T-1} + v_{T-2..T} -> temporal + predictor -> t_T

`Stage.loss(model, batch) -> (loss, loss_dict)` (LeRobot's `policy.forward` contract):
loss is the scalar to back-propagate, loss_dict its terms and the VQ statistics. The
trainer's loop (`handtouch.train.run_stage`) knows nothing else about a stage.
Stage 2 also replays stage 1's reconstruction (LossConfig.lambda_replay) because it
fine-tunes the encoder, VQ and decoder that reconstruction shares. Stage 3 is the paper's
|t_T - t^_T|^2 alone unless LossConfig.stage3_replay / stage3_vq opt in to a replay of
t_T's reconstruction and to the VQ terms (docs/HANDTOUCH.md, "Stage-3 loss"). Every loss ignores
uncovered pixels (coverage 0).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import torch
import torch.nn as nn

from htdata.errors import ArgumentError
from htdata.read import keys

from .config import MODULE_NAMES, WINDOW, LossConfig, MaskingConfig, StageConfig, TrainConfig
from .masking import sample_masks
from .model import HandTouch, covered, masked_mse

FRAMES = "frames"      # TrainData.frames: TactileFrameDataset items
WINDOWS = "windows"    # TrainData.windows: TactileWindowDataset items (WINDOW frames)
MASK = "mask"          # batch key the trainer adds for stage 2: (B,1,H,W) float, 1 = hidden


@dataclass(frozen=True)
class StepInfo:
    """Where the loop is, for stages whose batch preparation depends on it."""
    step: int       # 0-based step of this stage
    steps: int      # the stage's total steps
    rank: int = 0   # DDP rank (each rank draws its own masks)


@dataclass
class Losses:
    """What a stage's forward pass produced, before the VQ terms are added."""
    main: torch.Tensor                 # the stage's weighted reconstruction / prediction loss
    terms: dict[str, torch.Tensor]     # its unweighted terms, for the log
    vq: dict[str, torch.Tensor]        # FactorisedVQ losses (codebook, commit)
    stats: dict[str, torch.Tensor] = field(default_factory=dict)   # FactorisedVQ statistics


class Stage(ABC):
    """One training stage. `cfg` holds its schedule and trainable module names."""

    number: ClassVar[int]
    data: ClassVar[str]           # FRAMES or WINDOWS
    items: ClassVar[str]          # what one item is, for error messages
    reads_rgb: ClassVar[bool] = True   # False: its items need no RGB frame (none is decoded or sent)

    def __init__(self, cfg: StageConfig, weights: LossConfig | None = None):
        self.cfg = cfg
        self.weights = weights or LossConfig()

    @property
    def trainable(self) -> tuple[str, ...]:
        return tuple(self.cfg.trainable)

    @property
    def frozen(self) -> tuple[str, ...]:
        return tuple(n for n in MODULE_NAMES if n not in self.cfg.trainable)

    def configure(self, model: HandTouch) -> None:
        """Train exactly this stage's modules; freeze (and put in eval mode) the others. Parameters
        of trained modules that this stage's loss never reaches are frozen too (`unused`): DDP
        requires every trainable parameter to get a gradient."""
        model.set_trainable(self.trainable)
        for p in self.unused(model):
            p.requires_grad_(False)

    def unused(self, model: HandTouch) -> list[nn.Parameter]:
        """Parameters of this stage's modules that get no gradient under the model's switches and
        this stage's loss: the VQ without a codebook (bypassed), the codebook when the VQ terms
        have weight 0 (the straight-through path skips it), the RGB projection without vision."""
        out = []
        if "vq" in self.trainable and not model.cfg.quantised:
            out += list(model.vq.parameters())
        elif "vq" in self.trainable and not self.vq_weight:
            out.append(model.vq.codebook)
        if "rgb_proj" in self.trainable and not model.cfg.vision:
            out += list(model.rgb_proj.parameters())
        return out

    def prepare(self, batch: dict, at: StepInfo) -> dict:
        """The batch as this stage's loss reads it (already on the training device)."""
        return batch

    @abstractmethod
    def forward(self, model: HandTouch, batch: dict) -> Losses:
        """Run the model on a prepared batch."""

    @property
    def vq_weight(self) -> float:
        """Weight of the VQ codebook + commitment terms in this stage's loss."""
        return self.weights.vq_weight

    def loss(self, model: HandTouch, batch: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """-> (loss, {"vq", the stage's terms, VQ statistics}); "vq" is logged even when its weight is 0."""
        out = self.forward(model, batch)
        vq_total = out.vq["codebook"] + out.vq["commit"]
        # weight 0: left out of the graph, so the codebook gets no (zero) gradient and AdamW's
        # weight decay and momentum leave it alone
        loss = out.main + self.vq_weight * vq_total if self.vq_weight else out.main
        device = out.main.device
        return loss, {"vq": vq_total, **out.terms, **{k: v.to(device) for k, v in out.stats.items()}}


class Reconstruction(Stage):
    number, data, items = 1, FRAMES, "frame"
    reads_rgb = False

    def forward(self, model: HandTouch, batch: dict) -> Losses:
        cov = batch[keys.COVERAGE]
        target = covered(batch[keys.TACTILE], cov)
        pred, _, vq_l, stats = model.quantise_decode(model.encode(target), cov)
        recon = masked_mse(pred, target, cov)
        return Losses(recon, {"recon": recon}, vq_l, stats)


def mask_generator(seed: int, stage: int, step: int, rank: int) -> torch.Generator:
    """Per-step generator: masks depend only on (seed, stage, step, rank), so resumes repeat them."""
    return torch.Generator().manual_seed(((seed * 7 + stage) * 1_000_003 + step) * 131 + rank)


class MaskedFusion(Stage):
    number, data, items = 2, FRAMES, "frame"

    def __init__(self, cfg: StageConfig, weights: LossConfig | None = None,
                 masking: MaskingConfig | None = None, seed: int = 0):
        super().__init__(cfg, weights)
        self.masking = masking or MaskingConfig()
        self.seed = seed

    def prepare(self, batch: dict, at: StepInfo) -> dict:
        """Add this step's curriculum mask (regional or complete): the draws on the CPU (its
        generator), the mask built where the regions are (no copy back to the host)."""
        m = self.masking
        g = at.step / max(at.steps - 1, 1) if m.curriculum else 0.5   # 0.5: P_full's midpoint
        mask, _ = sample_masks(batch[keys.REGIONS], g, m.p_min, m.p_max, m.max_parts,
                               mask_generator(self.seed, self.number, at.step, at.rank))
        return {**batch, MASK: mask}

    def forward(self, model: HandTouch, batch: dict) -> Losses:
        mask = batch.get(MASK)
        if mask is None:
            raise ValueError(f"stage 2 needs a mask (batch[{MASK!r}], added by MaskedFusion.prepare)")
        cov = batch[keys.COVERAGE]
        target = covered(batch[keys.TACTILE], cov)
        b = target.shape[0]
        # one encoder call: the masked maps (for fusion) and the whole maps (replay)
        feats = model.rgb_features(batch[keys.RGB])                     # one backbone pass for both uses
        fill = model.rgb_fill(batch[keys.RGB], batch[keys.HAND], cov, feats)   # hidden pixels' RGB prior, if on
        tokens = model.encode(torch.cat([target, target]), torch.cat([mask, torch.zeros_like(mask)]),
                              None if fill is None else torch.cat([fill, torch.zeros_like(fill)]))
        fused = model.fuse(tokens[:b], batch[keys.RGB], batch[keys.HAND], feats)
        maps, _, vq_l, stats = model.quantise_decode(torch.cat([fused, tokens[b:]]), torch.cat([cov, cov]))
        pred = maps[:b]
        terms = {"visible": masked_mse(pred, target, cov * (1 - mask)),
                 "masked": masked_mse(pred, target, cov * mask),
                 "replay": masked_mse(maps[b:], target, cov)}
        w = self.weights
        main = w.lambda_vis * terms["visible"] + w.lambda_mask * terms["masked"] + w.lambda_replay * terms["replay"]
        return Losses(main, terms, vq_l, stats)


class NextFramePrediction(Stage):
    """The paper's |t_T - t^_T|^2 (covered pixels); opt-in: + stage3_replay x the reconstruction
    of t_T (encoder -> VQ -> decoder), + vq_weight x the VQ terms when stage3_vq."""

    number, data, items = 3, WINDOWS, "window (T >= 2)"

    @property
    def vq_weight(self) -> float:
        return self.weights.vq_weight if self.weights.stage3_vq else 0.0

    def forward(self, model: HandTouch, batch: dict) -> Losses:
        tac, cov = batch[keys.TACTILE], batch[keys.COVERAGE]
        if tac.dim() != 5 or tac.shape[1] != WINDOW:
            raise ValueError(f"stage 3 needs window batches (B,{WINDOW},1,H,W), got {tuple(tac.shape)}")
        cov_w = cov if cov.dim() == 5 else cov[:, None].expand(-1, WINDOW, -1, -1, -1)  # coverage may be given once
        cov_t = cov_w[:, -1]
        frames = covered(tac, cov_w)
        target = frames[:, -1]
        replay = self.weights.stage3_replay > 0
        # past frames (+ t_T when replaying) in one encoder call
        tokens = model.encode_frames(frames if replay else frames[:, :-1])
        pred_tokens = model.predicted_tokens(batch[keys.RGB], tokens[:, :WINDOW - 1], batch[keys.HAND])
        b = target.shape[0]
        if not replay:
            pred, _, vq_l, stats = model.quantise_decode(pred_tokens, cov_t)
            terms = {"next": masked_mse(pred, target, cov_t)}
            return Losses(terms["next"], terms, vq_l, stats)
        maps, _, vq_l, stats = model.quantise_decode(torch.cat([pred_tokens, tokens[:, -1]]),
                                                     torch.cat([cov_t, cov_t]))
        terms = {"next": masked_mse(maps[:b], target, cov_t), "replay": masked_mse(maps[b:], target, cov_t)}
        return Losses(terms["next"] + self.weights.stage3_replay * terms["replay"], terms, vq_l, stats)


STAGES: dict[int, type[Stage]] = {s.number: s for s in (Reconstruction, MaskedFusion, NextFramePrediction)}


def build_stage(n: int, cfg: TrainConfig) -> Stage:
    """Stage n with its settings from a TrainConfig."""
    if n not in STAGES:
        raise ArgumentError(f"stage must be one of {sorted(STAGES)}, got {n}")
    if STAGES[n] is MaskedFusion:
        return MaskedFusion(cfg.stage(n), cfg.loss, cfg.masking, cfg.seed)
    return STAGES[n](cfg.stage(n), cfg.loss)


def build_stages(cfg: TrainConfig) -> list[Stage]:
    """The configured stages, in run order."""
    return [build_stage(n, cfg) for n in cfg.stages]


class StageLoss(nn.Module):
    """The model under one stage's loss, as one module: DDP wraps this, so the loss runs
    inside DDP's forward and gradients are all-reduced. The model's weights are its own."""

    def __init__(self, stage: Stage, model: HandTouch):
        super().__init__()
        self.stage = stage
        self.model = model

    def forward(self, batch: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return self.stage.loss(self.model, batch)
