"""Batched SSIM in torch, matching `skimage.metrics.structural_similarity`.

Reference settings (skimage defaults with an explicit data_range):
7x7 uniform window, K1 = 0.01, K2 = 0.03, sample covariance (N/(N-1)),
mean of the SSIM image over the valid region only (skimage crops
(win-1)/2 pixels from every border, so padding never matters and only
"valid" windows are computed here).

Box means use a 2-D cumulative sum (about 8x faster than avg_pool2d with
stride 1 on CPU). Per-map statistics (window mean and variance) are cached
in `MapStats`, so scoring one query against many candidates only needs the
cross term, one box filter per pair.

Precision: sums are taken in float64 (variance = E[x^2] - E[x]^2 cancels
badly in float32); cached statistics are stored in float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

K1 = 0.01
K2 = 0.03
WIN_SIZE = 7


def _check_data_range(data_range: float | None) -> float:
    if data_range is None or not float(data_range) > 0:
        raise ValueError(f"SSIM needs an explicit data_range > 0 (got {data_range!r}); "
                         "tactile maps in [0,1] use data_range=1.0")
    return float(data_range)


def _as_maps(x, name: str) -> torch.Tensor:
    """Accept (H,W), (B,H,W) or (B,1,H,W) arrays/tensors -> (B,H,W) float64."""
    t = torch.as_tensor(x)
    if t.ndim == 4 and t.shape[1] == 1:
        t = t[:, 0]
    elif t.ndim == 2:
        t = t[None]
    if t.ndim != 3:
        raise ValueError(f"{name}: expected (H,W), (B,H,W) or (B,1,H,W), got shape {tuple(t.shape)}")
    if t.shape[-1] < WIN_SIZE or t.shape[-2] < WIN_SIZE:
        raise ValueError(f"{name}: maps of shape {tuple(t.shape[-2:])} are smaller than the "
                         f"{WIN_SIZE}x{WIN_SIZE} SSIM window")
    t = t.to(torch.float64)
    if not torch.isfinite(t).all():
        raise ValueError(f"{name}: maps contain NaN or Inf")
    return t


def box_mean_valid(x: torch.Tensor, win: int = WIN_SIZE) -> torch.Tensor:
    """Mean over every fully-inside win x win window: (..., H, W) -> (..., H-win+1, W-win+1)."""
    c = torch.nn.functional.pad(x.to(torch.float64), (1, 0, 1, 0)).cumsum(-1).cumsum(-2)
    s = c[..., win:, win:] - c[..., :-win, win:] - c[..., win:, :-win] + c[..., :-win, :-win]
    return s / (win * win)


@dataclass
class MapStats:
    """Cached per-map window statistics for SSIM (maps kept in float64 for the cross term)."""

    maps: torch.Tensor   # (N,H,W) float64
    mu: torch.Tensor     # (N,h,w) float32, window means
    var: torch.Tensor    # (N,h,w) float32, sample variances

    def __len__(self) -> int:
        return self.maps.shape[0]


def map_stats(maps, win: int = WIN_SIZE) -> MapStats:
    """Window mean and sample variance of every map, computed once."""
    m = _as_maps(maps, "maps")
    mu = box_mean_valid(m, win)
    cov_norm = win * win / (win * win - 1.0)
    var = cov_norm * (box_mean_valid(m * m, win) - mu * mu)
    return MapStats(maps=m, mu=mu.float(), var=var.float())


def _ssim_from_parts(mu_a, var_a, mu_b, var_b, mu_ab, data_range: float, win: int) -> torch.Tensor:
    """Mean SSIM from window statistics; mu_ab = window mean of a*b. Returns (...,) float64."""
    mu_a = mu_a.double()
    mu_b = mu_b.double()
    cov_norm = win * win / (win * win - 1.0)
    cov = cov_norm * (mu_ab - mu_a * mu_b)
    c1 = (K1 * data_range) ** 2
    c2 = (K2 * data_range) ** 2
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a * mu_a + mu_b * mu_b + c1) * (var_a.double() + var_b.double() + c2)
    return (num / den).mean(dim=(-2, -1))


def ssim(a, b, *, data_range: float | None, win: int = WIN_SIZE) -> torch.Tensor:
    """Elementwise SSIM of two batches of maps: (B,H,W) x (B,H,W) -> (B,) float64."""
    dr = _check_data_range(data_range)
    sa, sb = map_stats(a, win), map_stats(b, win)
    if sa.maps.shape != sb.maps.shape:
        raise ValueError(f"SSIM inputs differ in shape: {tuple(sa.maps.shape)} vs {tuple(sb.maps.shape)}")
    mu_ab = box_mean_valid(sa.maps * sb.maps, win)
    return _ssim_from_parts(sa.mu, sa.var, sb.mu, sb.var, mu_ab, dr, win)


def ssim_query_candidates(stats: MapStats, queries: torch.Tensor, candidates: torch.Tensor, *,
                          data_range: float | None, win: int = WIN_SIZE) -> torch.Tensor:
    """SSIM of map `queries[q]` against maps `candidates[q, c]` (indices into `stats`).

    queries (Q,) long, candidates (Q,C) long -> (Q,C) float64. Uses the cached
    statistics; only the window mean of the product is computed per pair.
    """
    dr = _check_data_range(data_range)
    queries = torch.as_tensor(queries, dtype=torch.long)
    candidates = torch.as_tensor(candidates, dtype=torch.long)
    if candidates.ndim != 2 or queries.shape != candidates.shape[:1]:
        raise ValueError(f"queries (Q,) and candidates (Q,C) expected, got {tuple(queries.shape)} "
                         f"and {tuple(candidates.shape)}")
    out = torch.empty(candidates.shape, dtype=torch.float64)
    for row, (q, cands) in enumerate(zip(queries.tolist(), candidates)):
        prod = stats.maps[q][None] * stats.maps[cands]          # (C,H,W)
        mu_ab = box_mean_valid(prod, win)
        out[row] = _ssim_from_parts(stats.mu[q][None], stats.var[q][None], stats.mu[cands],
                                    stats.var[cands], mu_ab, dr, win)
    return out
