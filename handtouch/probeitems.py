"""The RGB probes' training items: a part's frames decoded to what a probe reads (rgb_pretrain).

A probe keeps, per frame, the RGB pooled to its encoder's input size and each hand's coarse
contact map (the mean over the covered pixels of each canvas cell), never the full-size frame or
map: the smoke's ~3,000 train frames fit in ~150 MB. `load_items` decodes them in batches of
PROBE_BATCH.
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

PROBE_BATCH = 64    # frames decoded, pooled and reduced together

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


def load_items(dataset_root, split: str | None, part: str | None, cfg) -> ProbeItems:
    """Decode a seeded subsample of a part's frames (htdata.read.torchdata) into ProbeItems.

    Args:
        dataset_root: the dataset folder.
        split: the split file's name (None: the whole dataset).
        part: the split's part (None: every frame).
        cfg: the probe settings, an rgb_pretrain.RGBPretrainConfig (its arch's input size and grid,
            max_items, seed).
    """
    ds = TactileFrameDataset(str(dataset_root), options=ItemOptions(split=split, part=part))
    if len(ds) < 2:
        raise ArgumentError(f"{dataset_root}: part {part!r} of split {split!r} has {len(ds)} frames; "
                            "the RGB pretraining needs at least 2")
    fps_of = np.array([float(ep.get("fps") or 0.0) for ep in ds.reader.episodes])
    size, grid = cfg.arch["size"], cfg.arch["grid"]
    # in this process: decoding them in DataLoader workers took 6.2 -> 4.3 s on 2 cores, but the probe trained
    # on them next ran 35-40% slower in the process that had forked the workers (300 steps: 8.0-8.4 s -> 11.0-11.6 s)
    rgb, cells, weight, hand, episode, frame = [], [], [], [], [], []
    for b in iterate_batches(ds, subsample(len(ds), cfg.max_items, cfg.seed), PROBE_BATCH):
        rgb.append(F.adaptive_avg_pool2d(to_unit_float(b[keys.RGB]), size))
        c, w = coarse_target(b[keys.TACTILE], b[keys.COVERAGE], grid)
        cells.append(c)
        weight.append(w)
        hand.append(b[keys.HAND].reshape(-1).long())
        episode.append(b[keys.EPISODE].reshape(-1).numpy())
        frame.append(b[keys.FRAME].reshape(-1).numpy())
    episode = np.concatenate(episode)
    return ProbeItems(torch.cat(rgb), torch.cat(cells), torch.cat(weight), torch.cat(hand), episode,
                      np.concatenate(frame), fps_of[episode])
