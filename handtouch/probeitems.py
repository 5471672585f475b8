"""The RGB probes' training items: a part's frames decoded to what a probe reads (rgb_pretrain).

A probe keeps, per frame, the RGB pooled to its encoder's input size and each hand's coarse
contact map (the mean over the covered pixels of each canvas cell), never the full-size frame or
map: the smoke's ~3,000 train frames fit in ~150 MB. `load_items` decodes them in batches of
PROBE_BATCH, in this process or in worker processes (the same batches, so the same items).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from htdata.errors import ArgumentError
from htdata.read import keys
from htdata.read.itemoptions import ItemOptions
from htdata.read.torchdata import TactileFrameDataset

from .bench.items import iterate_batches, subsample
from .rgb_encoder import to_unit_float

PROBE_BATCH = 64    # frames decoded, pooled and reduced together (one worker task)

@dataclass
class ProbeItems:
    """Decoded frames for the probe: full-size RGB / maps are not kept for training items."""
    rgb: torch.Tensor        # (N,3,S,S) float [0,1], pooled to the encoder's input size
    cells: torch.Tensor      # (N,1,G,G) mean contact over the covered pixels of each canvas cell
    weight: torch.Tensor     # (N,1,G,G) 1 where the cell has a covered pixel
    hand: torch.Tensor       # (N,) long
    episode: np.ndarray      # (N,) episode positions
    frame: np.ndarray        # (N,) frame numbers
    fps: np.ndarray          # (N,) the item's episode fps


def coarse_target(tactile: torch.Tensor, coverage: torch.Tensor, grid: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(B,1,H,W) map + coverage -> per-cell mean over covered pixels (B,1,G,G), cell has-coverage weight."""
    cov = (coverage > 0.5).float()
    mass = F.adaptive_avg_pool2d(torch.where(cov > 0, tactile.float(), torch.zeros(())), grid)
    frac = F.adaptive_avg_pool2d(cov, grid)
    return mass / frac.clamp_min(1e-6), (frac > 0).float()


def load_items(dataset_root, split: str | None, part: str | None, cfg,
               workers: int = 0) -> ProbeItems:
    """Decode a seeded subsample of a part's frames (htdata.read.torchdata) into ProbeItems.

    Args:
        dataset_root: the dataset folder.
        split: the split file's name (None: the whole dataset).
        part: the split's part (None: every frame).
        cfg: the probe settings, an rgb_pretrain.RGBPretrainConfig (its arch's input size and grid,
            max_items, seed).
        workers: decoding processes (0: in this one). Each decodes and pools whole batches of
            PROBE_BATCH frames, the same batches in the same order, so the items are the same
            for any count; 2 halve the ~8 s a smoke's train part takes on one core.
    """
    ds = TactileFrameDataset(str(dataset_root), options=ItemOptions(split=split, part=part))
    if len(ds) < 2:
        raise ArgumentError(f"{dataset_root}: part {part!r} of split {split!r} has {len(ds)} frames; "
                            "the RGB pretraining needs at least 2")
    fps_of = np.array([float(ep.get("fps") or 0.0) for ep in ds.reader.episodes])
    batches = _ProbeBatches(ds, subsample(len(ds), cfg.max_items, cfg.seed), cfg.arch["size"], cfg.arch["grid"])
    if workers > 0:
        loader = torch.utils.data.DataLoader(batches, batch_size=None, num_workers=min(workers, len(batches)))
    else:
        loader = (batches[i] for i in range(len(batches)))
    got = list(loader)
    episode = np.concatenate([b["episode"].numpy() for b in got])
    return ProbeItems(*(torch.cat([b[k] for b in got]) for k in ("rgb", "cells", "weight", "hand")), episode,
                      np.concatenate([b["frame"].numpy() for b in got]), fps_of[episode])



class _ProbeBatches(torch.utils.data.Dataset):
    """Batch i of the probe's items: PROBE_BATCH frames decoded, the RGB pooled to the encoder's input
    size and the map reduced to its coarse cells (all the probe keeps), where the batch is decoded."""

    def __init__(self, ds: TactileFrameDataset, indices: np.ndarray, size: int, grid: int):
        self.ds, self.indices, self.size, self.grid = ds, indices, size, grid

    def __len__(self) -> int:
        return -(-len(self.indices) // PROBE_BATCH)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        b = next(iterate_batches(self.ds, self.indices[i * PROBE_BATCH:(i + 1) * PROBE_BATCH], PROBE_BATCH))
        cells, weight = coarse_target(b[keys.TACTILE], b[keys.COVERAGE], self.grid)
        return {"rgb": F.adaptive_avg_pool2d(to_unit_float(b[keys.RGB]), self.size), "cells": cells,
                "weight": weight, "hand": b[keys.HAND].reshape(-1).long(),
                "episode": b[keys.EPISODE].reshape(-1), "frame": b[keys.FRAME].reshape(-1)}
