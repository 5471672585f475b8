"""Batched SSIM in torch, matching `skimage.metrics.structural_similarity`.

Reference settings (skimage defaults with an explicit data_range):
7x7 uniform window, K1 = 0.01, K2 = 0.03, sample covariance (N/(N-1)),
mean of the SSIM image over the valid region only (skimage crops
(win-1)/2 pixels from every border, so padding never matters and only
"valid" windows are computed here).

Precision: every window statistic (mean, variance, covariance) and the SSIM
formula are float64. Window sums are direct sums of 7 then 7 values
(separable), not a running 2-D cumulative sum: a cumulative sum over a
224x224 map carries rounding error proportional to the whole map's mass
(~1e-12 on a constant map), a 7-term sum only ~1e-16. float32 statistics are
not enough: variance is E[x^2] - E[x]^2, and an error of 1e-8 in a window
mean becomes ~4e-5 in the SSIM of a constant map against itself, larger
than real differences between near-identical maps (those then rank in the
wrong order against skimage).

Defined cases (no 0/0): C1 = (K1 R)^2 and C2 = (K2 R)^2 are > 0 because
data_range R > 0 is required, so both denominators are >= C1 and >= C2.
A constant map c against a constant map d scores
(2cd + C1) / (c^2 + d^2 + C1) (variances are 0, the structure term is
C2 / C2 = 1); two empty (all-zero) maps score exactly 1. An empty batch
gives an empty result.

Per-map statistics (window mean, its square, variance) are cached in
`MapStats`, so scoring one query against many candidates needs only the
cross term, one box filter of the product per pair.
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
    """float64 mean over every fully-inside win x win window: (..., H, W) -> (..., H-win+1, W-win+1).

    Separable direct sums (rows, then columns): as fast as a 2-D cumulative
    sum on CPU and exact to ~1e-16 (see the module doc).
    """
    x = x.to(torch.float64)
    return x.unfold(-1, win, 1).sum(-1).unfold(-2, win, 1).sum(-1).div_(win * win)


@dataclass
class MapStats:
    """Cached float64 per-map window statistics for SSIM."""

    maps: torch.Tensor     # (N,H,W) float64
    mu: torch.Tensor       # (N,h,w) window means
    mu_sq: torch.Tensor    # (N,h,w) mu * mu
    var: torch.Tensor      # (N,h,w) sample variances

    def __len__(self) -> int:
        return self.maps.shape[0]


def map_stats(maps, win: int = WIN_SIZE) -> MapStats:
    """Window mean and sample variance of every map, computed once."""
    m = _as_maps(maps, "maps")
    mu = box_mean_valid(m, win)
    mu_sq = mu * mu
    cov_norm = win * win / (win * win - 1.0)
    var = (box_mean_valid(m * m, win) - mu_sq).mul_(cov_norm)
    return MapStats(maps=m, mu=mu, mu_sq=mu_sq, var=var)


def _ssim_from_parts(a: MapStats | tuple, b: MapStats | tuple, mu_ab: torch.Tensor, data_range: float,
                     win: int) -> torch.Tensor:
    """Mean SSIM from window statistics, all float64.

    a, b: (mu, mu_sq, var) tensors broadcastable to mu_ab (the window mean of
    a*b). Returns (...,). In-place steps keep the per-pair temporaries few.
    """
    (mu_a, mu_sq_a, var_a), (mu_b, mu_sq_b, var_b) = a, b
    cov_norm = win * win / (win * win - 1.0)
    c1 = (K1 * data_range) ** 2
    c2 = (K2 * data_range) ** 2
    mm = mu_a * mu_b
    structure = (mu_ab - mm).mul_(2 * cov_norm).add_(c2)           # 2 cov + C2
    num = mm.mul_(2).add_(c1).mul_(structure)                       # (2 mu_a mu_b + C1)(2 cov + C2)
    den = torch.add(mu_sq_a, mu_sq_b).add_(c1).mul_(torch.add(var_a, var_b).add_(c2))
    return num.div_(den).mean(dim=(-2, -1))


def _parts(stats: MapStats, index) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return stats.mu[index], stats.mu_sq[index], stats.var[index]


def ssim(a, b, *, data_range: float | None, win: int = WIN_SIZE) -> torch.Tensor:
    """Elementwise SSIM of two batches of maps: (B,H,W) x (B,H,W) -> (B,) float64."""
    dr = _check_data_range(data_range)
    sa, sb = map_stats(a, win), map_stats(b, win)
    if sa.maps.shape != sb.maps.shape:
        raise ValueError(f"SSIM inputs differ in shape: {tuple(sa.maps.shape)} vs {tuple(sb.maps.shape)}")
    mu_ab = box_mean_valid(sa.maps * sb.maps, win)
    return _ssim_from_parts((sa.mu, sa.mu_sq, sa.var), (sb.mu, sb.mu_sq, sb.var), mu_ab, dr, win)


def ssim_query_candidates(stats: MapStats, queries: torch.Tensor, candidates: torch.Tensor, *,
                          data_range: float | None, win: int = WIN_SIZE) -> torch.Tensor:
    """SSIM of map `queries[q]` against maps `candidates[q, c]` (indices into `stats`).

    queries (Q,) long, candidates (Q,C) long -> (Q,C) float64. Uses the cached
    statistics; only the window mean of the product is computed per pair.
    Pairs are scored one at a time on purpose: a pair's float64 temporaries
    (~0.4 MB at 224x224) stay in cache, while a (C,h,w) batch of them is
    memory-bound (measured ~2x slower for C = 20 on CPU).
    """
    dr = _check_data_range(data_range)
    queries = torch.as_tensor(queries, dtype=torch.long)
    candidates = torch.as_tensor(candidates, dtype=torch.long)
    if candidates.ndim != 2 or queries.shape != candidates.shape[:1]:
        raise ValueError(f"queries (Q,) and candidates (Q,C) expected, got {tuple(queries.shape)} "
                         f"and {tuple(candidates.shape)}")
    out = torch.empty(candidates.shape, dtype=torch.float64)
    for row, (q, cands) in enumerate(zip(queries.tolist(), candidates.tolist())):
        query = _parts(stats, q)
        for col, c in enumerate(cands):
            mu_ab = box_mean_valid(stats.maps[q] * stats.maps[c], win)
            out[row, col] = _ssim_from_parts(query, _parts(stats, c), mu_ab, dr, win)
    return out
