"""Stage-2 masks: regional (anatomical parts) or complete, on a curriculum.

P_full(g) = p_min + (p_max - p_min) / (1 + exp(-12 (g - 0.5))), g = stage progress in [0,1].
Each sample is completely masked with probability P_full(g); otherwise 1..max_parts
of the parts thumb, index, middle, ring, little, palm (part ids 1..6) are
chosen and the mask is exactly those parts' pixels.
"""

from __future__ import annotations

import math

import torch

NUM_PARTS = 6
CURRICULUM_STEEPNESS = 12.0


def p_full(g: float, p_min: float, p_max: float) -> float:
    if not 0.0 <= g <= 1.0:
        raise ValueError(f"curriculum progress g must be in [0,1], got {g}")
    return p_min + (p_max - p_min) / (1.0 + math.exp(-CURRICULUM_STEEPNESS * (g - 0.5)))


def to_device(t: torch.Tensor, device: torch.device | str) -> torch.Tensor:
    """A CPU-drawn tensor on `device`: pinned and non_blocking on CUDA (a copy from pageable memory
    waits for the device's queue first: a host sync every step)."""
    device = torch.device(device)
    if device.type == "cuda":
        return t.pin_memory().to(device, non_blocking=True)
    return t.to(device)


def choose_parts(batch: int, max_parts: int, generator: torch.Generator | None = None,
                 device: torch.device | str = "cpu") -> torch.Tensor:
    """(B, 7) bool: column p is True when part p is masked; column 0 (outside) never is."""
    if not 1 <= max_parts <= NUM_PARTS:
        raise ValueError(f"max_parts must be in 1..{NUM_PARTS}, got {max_parts}")
    k = torch.randint(1, max_parts + 1, (batch, 1), generator=generator)
    scores = torch.rand(batch, NUM_PARTS, generator=generator)
    rank = scores.argsort(dim=1).argsort(dim=1)          # a random permutation per sample
    chosen = rank < k
    return to_device(torch.cat([torch.zeros(batch, 1, dtype=torch.bool), chosen], dim=1), device)


def part_mask(regions: torch.Tensor, chosen: torch.Tensor) -> torch.Tensor:
    """regions (B,H,W) part ids 0..6, chosen (B,7) bool -> mask (B,1,H,W) float, 1 = hidden."""
    if regions.dim() != 3:
        raise ValueError(f"regions must be (B,H,W), got {tuple(regions.shape)}")
    ids = regions.long()
    # checked on the CPU only: on an accelerator reading min / max back would stop it every step
    if ids.device.type == "cpu" and ids.numel() and (int(ids.max()) > NUM_PARTS or int(ids.min()) < 0):
        raise ValueError(f"regions hold part ids outside 0..{NUM_PARTS}: "
                         f"[{int(ids.min())}, {int(ids.max())}]")
    b, h, w = ids.shape
    hidden = torch.gather(to_device(chosen, ids.device), 1, ids.reshape(b, -1)).reshape(b, 1, h, w)
    return hidden.float()


def sample_masks(regions: torch.Tensor, g: float, p_min: float, p_max: float, max_parts: int,
                 generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (mask (B,1,H,W) float, complete (B,) bool) following the curriculum at progress g."""
    b = regions.shape[0]
    complete = torch.rand(b, generator=generator) < p_full(g, p_min, p_max)
    regional = part_mask(regions, choose_parts(b, max_parts, generator))
    full = torch.ones_like(regional)
    complete = to_device(complete, regional.device)
    mask = torch.where(complete.view(b, 1, 1, 1), full, regional)
    return mask, complete
