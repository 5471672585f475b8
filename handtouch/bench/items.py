"""HT-Bench's evaluation items: each part decoded once, with everything model-independent fixed.

Items: at most `max_items` frames (and windows) per part, drawn without
replacement by a seeded RNG, sorted, so every model sees the same items.

Data: a dataset root (str/Path: parts are loaded with htdata.read.torchdata), or
in-memory `EvalPart`s (a Mapping part -> EvalPart, or one EvalPart scored as
part "all"). An `EvalPart` holds Dataset-like objects (len + getitem -> dict
of tensors, docs/FORMAT.md "Reader / torch").

Several models: `prepare(...)` decodes each part once and fixes the
model-independent parts (items, inpainting masks: one covered anatomical part
per frame, drawn by a seeded RNG; the retrieval SSIM reference); the scoring
(handtouch.bench.evaluate) takes its result for every model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from handtouch.bench.retrieval import RetrievalConfig, RetrievalReference, retrieval_reference
from handtouch.config import WINDOW
from htdata.errors import ArgumentError
from htdata.read import keys
from htdata.read.torchdata import TactileFrameDataset, TactileWindowDataset
from htdata.read.itemoptions import ItemOptions

NUM_PARTS = 6          # part ids 1..6 (thumb, index, middle, ring, little, palm)


@dataclass
class EvalConfig:
    max_items: int = 200
    seed: int = 0
    batch_size: int = 16
    num_candidates: int = 20
    exclude_radius: int = 5

    def validate(self) -> "EvalConfig":
        if self.max_items < 1 or self.batch_size < 1:
            raise ArgumentError(f"max_items and batch_size must be >= 1, got {self.max_items}, {self.batch_size}")
        RetrievalConfig(num_candidates=self.num_candidates, exclude_radius=self.exclude_radius).validate()
        return self


@dataclass
class EvalPart:
    """Dataset-like sources of one split part; `windows` may be None (prediction is then skipped)."""

    frames: Any
    windows: Any = None


def load_part(dataset_root: str | Path, split_name: str | None, part: str) -> EvalPart:
    """Open a committed dataset's part through htdata.read.torchdata (split None = whole dataset)."""

    root = str(dataset_root)
    return EvalPart(frames=TactileFrameDataset(root, options=ItemOptions(split=split_name, part=part)),
                    windows=TactileWindowDataset(root, window=WINDOW, options=ItemOptions(split=split_name, part=part)))


def subsample(n: int, max_items: int, seed: int) -> np.ndarray:
    """Sorted indices of at most max_items of n items, seeded."""
    if n <= max_items:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, max_items, replace=False))


def _collate(items: list[dict]) -> dict[str, torch.Tensor]:
    out = {}
    for key in items[0]:
        vals = [it[key] for it in items]
        if isinstance(vals[0], torch.Tensor):
            out[key] = torch.stack(vals)
        elif isinstance(vals[0], np.ndarray):
            out[key] = torch.from_numpy(np.stack(vals))
        elif isinstance(vals[0], (int, float, bool, np.integer, np.floating)):
            out[key] = torch.as_tensor(vals)
    return out


def iterate_batches(dataset, indices: np.ndarray, batch_size: int):
    for start in range(0, len(indices), batch_size):
        yield _collate([dataset[int(i)] for i in indices[start:start + batch_size]])


def _hand(batch: dict) -> torch.Tensor:
    """(B,) long; window items may carry a per-frame hand (B,W): the last frame's is used."""
    h = batch[keys.HAND]
    return (h[:, -1] if h.ndim == 2 else h.reshape(-1)).long()


def part_masks(regions: torch.Tensor, coverage: torch.Tensor, generator: np.random.Generator) -> torch.Tensor:
    """One covered anatomical part per frame -> mask (B,1,H,W) float, 1 = hidden.

    The part is drawn uniformly among the parts with at least one covered
    pixel in that frame; a frame with no covered part gets an empty mask
    (its H- metrics are then skipped, not faked).
    """
    covered = coverage[:, 0] > 0.5
    present = torch.stack([((regions == p) & covered).flatten(1).any(1) for p in range(1, NUM_PARTS + 1)], 1)
    draw = torch.from_numpy(generator.random(present.shape))
    choice = torch.where(present, draw, torch.full_like(draw, -1.0)).argmax(1) + 1   # part id 1..6
    choice = torch.where(present.any(1), choice, torch.zeros_like(choice))
    return (regions == choice[:, None, None].to(regions.dtype)).logical_and(choice[:, None, None] > 0)[:, None].float()


def _compact(x: torch.Tensor) -> torch.Tensor:
    """float16 if that is lossless (decoded EXR half maps are), else unchanged: halves cache memory."""
    if x.dtype == torch.float32:
        h = x.half()
        if torch.equal(h.float(), x):
            return h
    return x


@dataclass
class PreparedPart:
    """A part's evaluation items decoded once, in batches, with everything model-independent
    (inpainting masks, the retrieval SSIM reference) fixed, so every model sees the same."""

    frames: list[dict]          # tactile, coverage (u8), rgb, hand, episode, frame, mask (u8, 1 = hidden)
    windows: list[dict]         # rgb_window, tactile_window, coverage, hand, target, mask (u8, frame T)
    reference: RetrievalReference
    items: int
    num_windows: int


def prepare_part(part: EvalPart, cfg: EvalConfig) -> PreparedPart:
    cfg.validate()
    n = len(part.frames)
    if n == 0:
        raise ArgumentError("evaluation part has no frames")
    idx = subsample(n, cfg.max_items, cfg.seed)
    rng = np.random.default_rng(cfg.seed + 1)
    frames, maps, episodes, frame_ids = [], [], [], []
    for b in iterate_batches(part.frames, idx, cfg.batch_size):
        tactile, coverage = b[keys.TACTILE].float(), b[keys.COVERAGE].float()
        frames.append({keys.TACTILE: _compact(tactile), keys.COVERAGE: (coverage > 0.5).to(torch.uint8),
                       keys.RGB: b[keys.RGB], keys.HAND: _hand(b),
                       keys.EPISODE: b[keys.EPISODE].reshape(-1), keys.FRAME: b[keys.FRAME].reshape(-1),
                       "mask": part_masks(b[keys.REGIONS], coverage, rng).to(torch.uint8)})
        maps.append(tactile[:, 0])
        episodes.append(b[keys.EPISODE].reshape(-1))
        frame_ids.append(b[keys.FRAME].reshape(-1))
    reference = retrieval_reference(
        torch.cat(maps), torch.cat(episodes).numpy(), torch.cat(frame_ids).numpy(),
        RetrievalConfig(num_candidates=cfg.num_candidates, exclude_radius=cfg.exclude_radius, seed=cfg.seed))
    windows = []
    widx = np.zeros(0, np.int64)
    if part.windows is not None and len(part.windows) > 0:
        widx = subsample(len(part.windows), cfg.max_items, cfg.seed)
        wrng = np.random.default_rng(cfg.seed + 2)
        for b in iterate_batches(part.windows, widx, cfg.batch_size):
            rgb_w, tac_w, cov_t, hand, target = window_inputs(b)
            regions = b[keys.REGIONS][:, -1] if b[keys.REGIONS].ndim == 4 else b[keys.REGIONS]
            windows.append({"rgb_window": rgb_w, "tactile_window": _compact(tac_w),
                            "coverage": (cov_t > 0.5).to(torch.uint8), "hand": hand, "target": _compact(target),
                            # frame T's inpainting mask, for the predictions figure
                            "mask": part_masks(regions, cov_t, wrng).to(torch.uint8)})
    return PreparedPart(frames, windows, reference, int(len(idx)), int(len(widx)))


def window_inputs(b: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Window batch -> (rgb_window (B,W,3,H,W), tactile_window (B,W-1,1,H,W), coverage_T, hand, target_T)."""
    tactile = b[keys.TACTILE].float()
    coverage = b[keys.COVERAGE].float()
    cov_t = coverage[:, -1] if coverage.ndim == 5 else coverage
    return b[keys.RGB], tactile[:, :-1], cov_t, _hand(b), tactile[:, -1]


def resolve_parts(dataset_root, split_name: str | None, parts: Sequence[str]) -> dict[str, EvalPart | PreparedPart]:
    if isinstance(dataset_root, (EvalPart, PreparedPart)):
        return {"all": dataset_root}
    if isinstance(dataset_root, Mapping):
        missing = [p for p in parts if p not in dataset_root]
        if missing:
            raise KeyError(f"evaluation data has no part(s) {missing}; available: {sorted(dataset_root)}")
        return {p: dataset_root[p] if isinstance(dataset_root[p], (EvalPart, PreparedPart))
                else EvalPart(dataset_root[p]) for p in parts}
    return {p: load_part(dataset_root, split_name, p) for p in parts}


def prepare(dataset_root, split_name: str | None = None, parts: Sequence[str] = ("test", "ood"),
            cfg: EvalConfig | None = None) -> dict[str, PreparedPart]:
    """Decode and fix each part's items once (reuse the result for several models)."""
    cfg = (cfg or EvalConfig()).validate()
    return {name: src if isinstance(src, PreparedPart) else prepare_part(src, cfg)
            for name, src in resolve_parts(dataset_root, split_name, parts).items()}
