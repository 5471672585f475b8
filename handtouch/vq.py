"""Factorised vector quantiser with a separate usage EMA and noisy dead-code restarts.

z_e (B,N,D) -> W_in -> z (d) -> nearest code of a shared codebook (K,d) -> W_out -> (B,N,D).
Loss = ||z_q - sg[z]||^2 + beta ||sg[z_q] - z||^2, straight-through gradient.
Everything runs in float32, also under bf16 autocast: distances and argmin in
bf16 pick wrong codes. Nothing here reads a value back to the host (no .item(),
no boolean-mask indexing, no bincount, which sizes its output from the data):
usage, restarts and statistics stay tensors on the device, so a training step
on a GPU never waits for it.
"""

from __future__ import annotations

import torch
import torch.distributed as dist
import torch.nn as nn
import torch.nn.functional as F


def _distributed() -> bool:
    return dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1


class FactorisedVQ(nn.Module):
    def __init__(self, dim: int, code_dim: int, codebook_size: int, beta: float = 0.25,
                 dead_threshold: float = 1.0, usage_decay: float = 0.99, restart_noise: float = 0.01):
        super().__init__()
        self.beta = beta
        self.dead_threshold = dead_threshold
        self.usage_decay = usage_decay
        self.restart_noise = restart_noise
        self.w_in = nn.Linear(dim, code_dim)
        self.w_out = nn.Linear(code_dim, dim)
        self.codebook = nn.Parameter(torch.randn(codebook_size, code_dim) * code_dim ** -0.5)
        # Expected uses per training step, per code. Starts at 0: the first training
        # batch re-initialises every code from real projected features.
        self.register_buffer("usage", torch.zeros(codebook_size))

    @property
    def codebook_size(self) -> int:
        return self.codebook.shape[0]

    def forward(self, z_e: torch.Tensor):
        """z_e (B,N,D) -> (z_out (B,N,D) f32, indices (B,N) long, losses dict, stats dict)."""
        with torch.autocast(device_type=z_e.device.type, enabled=False):
            return self._quantise(z_e.float())

    def _quantise(self, z_e: torch.Tensor):
        b, n, _ = z_e.shape
        z = self.w_in(z_e).reshape(b * n, -1)
        restarts = torch.zeros((), device=z.device)
        if self.training:
            restarts = self._restart_dead_codes(z.detach())
        indices = self.nearest(z.detach())
        z_q = F.embedding(indices, self.codebook)
        counts = torch.zeros(self.codebook_size, device=z.device).index_add_(
            0, indices, torch.ones(indices.shape[0], device=z.device))
        if self.training and _distributed():   # identical usage (hence restarts) on every rank;
            dist.all_reduce(counts)              # eval may run on one rank only: no collective there
        if self.training:
            with torch.no_grad():
                self.usage.mul_(self.usage_decay).add_(counts, alpha=1 - self.usage_decay)
        losses = {
            "codebook": F.mse_loss(z_q, z.detach()),
            "commit": self.beta * F.mse_loss(z, z_q.detach()),
        }
        z_st = z + (z_q - z).detach()              # straight-through
        z_out = self.w_out(z_st).reshape(b, n, -1)
        probs = counts / counts.sum().clamp_min(1.0)
        entropy = -(probs * torch.log(probs.clamp_min(1e-12))).sum()
        stats = {
            "perplexity": torch.exp(entropy).detach(),
            "usage": (counts > 0).float().mean().detach(),
            "restarts": restarts,
        }
        return z_out, indices.reshape(b, n), losses, stats

    @torch.no_grad()
    def nearest(self, z: torch.Tensor) -> torch.Tensor:
        """Index of the nearest code (squared L2) for each row of z (M,d)."""
        cb = self.codebook.float()
        d2 = z.pow(2).sum(1, keepdim=True) - 2 * z @ cb.t() + cb.pow(2).sum(1)[None]
        return d2.argmin(dim=1)

    @torch.no_grad()
    def _restart_dead_codes(self, z: torch.Tensor) -> torch.Tensor:
        """Re-initialise codes whose usage EMA < threshold from random batch features + noise;
        -> the number restarted (a 0-d float tensor on z's device).

        Vectorised: a candidate is drawn for every code and `torch.where` keeps it for the dead
        ones only, so the host never learns how many died (asking would stop the device).
        Rank 0 draws the replacements and broadcasts the codebook, so ranks stay identical.
        """
        dead = self.usage < self.dead_threshold
        k, d = self.codebook.shape
        pick = torch.randint(0, z.shape[0], (k,), device=z.device)
        fresh = z[pick] + self.restart_noise * torch.randn(k, d, device=z.device)
        self.codebook.data.copy_(torch.where(dead[:, None], fresh.to(self.codebook.dtype), self.codebook.data))
        # Grace period: a restarted code gets log(2) / -log(decay) unused steps before it counts as dead.
        self.usage.copy_(torch.where(dead, torch.full_like(self.usage, 2.0 * self.dead_threshold), self.usage))
        if _distributed():
            dist.broadcast(self.codebook.data, src=0)
            dist.broadcast(self.usage, src=0)
        return dead.sum().float()
