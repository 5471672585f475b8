"""HT-Bench 1-vs-20 tactile retrieval, scored tie-aware and exactly.

Protocol (per query map q of the evaluation set):
- Candidates: `num_candidates` (C = 20) maps drawn without replacement by a
  seeded RNG from the evaluation set, EXCLUDING q itself and every frame of
  q's episode within +-`exclude_radius` frames (neighbouring frames are near
  duplicates and would make the task trivial). A query with fewer eligible
  maps than C is skipped and counted.
- Reference scores: SSIM(q, candidate) (skimage defaults, data_range 1).
- Model scores: cosine similarity of the model's embeddings.

Ties. Two scores of one query are tied when they differ by at most
`tie_tolerance` (TIE_TOL = 1e-10; groups are chained: sorted scores split
where the gap to the next exceeds the tolerance). Why 1e-10: float64 SSIM
evaluation noise is up to ~1e-12 (a bright constant map, where the variance
E[x^2] - E[x]^2 cancels; skimage itself returns 1 + 4e-13 there), so smaller
differences are not evidence of an order; the smallest difference the
tests require resolving in skimage's order is 1e-8 (constant 0.7 query,
candidates 0.70000003 vs 0.7001). Cosines of float32 embeddings, computed
in float64, differ by >= ~1e-8 unless equal.
- SSIM ties are equally right answers;
- embedding ties are broken uniformly at random, scored in expectation
  (exactly, no sampling).

Hit@1 = |G & E| / |E|, G the SSIM-maximal candidates, E the
embedding-maximal ones (the chance that a random tie-break of E picks a
member of G).

Recall@k (k = 5): S = candidates in SSIM groups wholly inside the top k; B =
the SSIM group straddling k-th place, with need = k - |S| slots left (B is
empty and need 0 when a group ends exactly at k-th place). An embedding
top-k set T scores |T & S| + min(need, |T & B|) (the best overlap over all
SSIM tie orders). T is the embedding's wholly-inside groups plus a uniformly
random subset of its own straddling group, so the count drawn from each of
S and B is hypergeometric; Recall@k = E[score] / k. Hit@1 is the k = 1 case.
Consequences: an embedding with the SSIM order and ties scores 1 even when
ties straddle k-th place; a constant embedding scores each query's chance
level (|G| / C for Hit@1).

Chance, reported next to every score: theoretical 1/C and k/C (no ties);
`constant_*`: a constant embedding, i.e. the per-query chance given the
SSIM ties (identical empty maps make it higher than 1/C); `shuffled_*`: the
model's own embeddings permuted across items (mean of `shuffle_rounds`
seeded permutations).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np
import torch

from handtouch.bench.ssim import map_stats, ssim_query_candidates
from htdata.errors import ConfigError

TIE_TOL = 1e-10   # scores of one query within this are tied (module doc: why this value)


@dataclass
class RetrievalConfig:
    num_candidates: int = 20
    top_k: int = 5
    exclude_radius: int = 5      # same-episode frames within +-radius of the query are never candidates
    max_queries: int | None = None
    seed: int = 0
    tie_tolerance: float = TIE_TOL
    shuffle_rounds: int = 10     # permutations averaged for the shuffled-embedding chance level

    def validate(self) -> "RetrievalConfig":
        if self.num_candidates < 1:
            raise ConfigError(f"num_candidates must be >= 1, got {self.num_candidates}")
        if not 1 <= self.top_k <= self.num_candidates:
            raise ConfigError(f"top_k must be in [1, num_candidates], got {self.top_k}")
        if self.exclude_radius < 0:
            raise ConfigError(f"exclude_radius must be >= 0, got {self.exclude_radius}")
        if self.max_queries is not None and self.max_queries < 1:
            raise ConfigError(f"max_queries must be >= 1 or None, got {self.max_queries}")
        if not self.tie_tolerance >= 0:
            raise ConfigError(f"tie_tolerance must be >= 0, got {self.tie_tolerance}")
        if self.shuffle_rounds < 1:
            raise ConfigError(f"shuffle_rounds must be >= 1, got {self.shuffle_rounds}")
        return self


def eligible_candidates(episodes: np.ndarray, frames: np.ndarray, query: int, exclude_radius: int) -> np.ndarray:
    """Dataset indices that may be candidates for `query` (sorted ascending)."""
    near = (episodes == episodes[query]) & (np.abs(frames.astype(np.int64) - int(frames[query])) <= exclude_radius)
    near[query] = True
    return np.flatnonzero(~near)


def draw_candidates(episodes, frames, cfg: RetrievalConfig) -> tuple[np.ndarray, np.ndarray, int]:
    """Seeded draw -> (queries (Q,), candidates (Q,C) sorted ascending per row, skipped count)."""
    cfg.validate()
    episodes = np.asarray(episodes)
    frames = np.asarray(frames)
    n = len(episodes)
    rng = np.random.default_rng(cfg.seed)
    order = np.arange(n) if cfg.max_queries is None or cfg.max_queries >= n else \
        np.sort(rng.choice(n, cfg.max_queries, replace=False))
    queries, cands, skipped = [], [], 0
    for q in order:
        pool = eligible_candidates(episodes, frames, int(q), cfg.exclude_radius)
        if len(pool) < cfg.num_candidates:
            skipped += 1
            continue
        queries.append(int(q))
        cands.append(np.sort(rng.choice(pool, cfg.num_candidates, replace=False)))
    if not queries:
        return np.zeros(0, np.int64), np.zeros((0, cfg.num_candidates), np.int64), skipped
    return np.asarray(queries, np.int64), np.stack(cands).astype(np.int64), skipped


def top_k_split(scores, k: int, tol: float = TIE_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks over one query's candidates -> (inside, straddling).

    inside: candidates in tie groups wholly within the top k; straddling: the
    tie group crossing k-th place (all False when a group ends exactly there).
    Ties: sorted scores split into groups where the gap exceeds `tol`.
    """
    scores = np.asarray(scores, np.float64)
    if scores.ndim != 1 or not 1 <= k <= len(scores):
        raise ValueError(f"need 1 <= k <= {len(scores)} scores of one query, got k = {k}, shape {scores.shape}")
    if not np.isfinite(scores).all():
        raise ValueError("retrieval scores contain NaN/Inf")
    order = np.argsort(-scores, kind="stable")
    ranked = scores[order]
    group = np.cumsum(np.r_[True, ranked[:-1] - ranked[1:] > tol]) - 1       # tie group per rank
    kth = group[k - 1]
    ends_at_k = k == len(ranked) or group[k] != kth
    inside, straddling = np.zeros(len(scores), bool), np.zeros(len(scores), bool)
    inside[order] = group <= kth if ends_at_k else group < kth
    straddling[order] = ~ends_at_k & (group == kth)
    return inside, straddling


def expected_top_k_score(reference, embedding, k: int, tol: float = TIE_TOL) -> float:
    """Exact expected Recall@k (Hit@1 for k = 1) of one query, in [0, 1] (module doc).

    reference: SSIM per candidate; embedding: model similarity per candidate.
    """
    if np.shape(reference) != np.shape(embedding):
        raise ValueError(f"reference {np.shape(reference)} and embedding {np.shape(embedding)} scores differ in shape")
    sure, tied = top_k_split(reference, k, tol)             # S, B
    need = k - int(sure.sum())
    taken, drawn_from = top_k_split(embedding, k, tol)      # the embedding's sure picks and its straddling group D
    slots, pool = k - int(taken.sum()), int(drawn_from.sum())
    from_sure, from_tied = int((drawn_from & sure).sum()), int((drawn_from & tied).sum())
    expected = (taken & sure).sum() + (slots * from_sure / pool if pool else 0.0)
    base = int((taken & tied).sum())
    if pool:   # |T & B| = base + X, X ~ Hypergeometric(pool, from_tied, slots)
        total = comb(pool, slots)
        expected += sum(comb(from_tied, x) * comb(pool - from_tied, slots - x) * min(need, base + x)
                        for x in range(min(from_tied, slots) + 1)) / total
    else:
        expected += min(need, base)
    return float(expected) / k


def cosine_scores(embeddings: torch.Tensor, queries: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """(Q,C) float64 cosine similarity; zero-norm embeddings give 0 similarity, never NaN.

    An elementwise product and a sum per pair (not a matmul, whose blocking can
    round equal pairs differently): identical embeddings give identical scores.
    """
    e = torch.as_tensor(embeddings).to(torch.float64)
    if not torch.isfinite(e).all():
        bad = (~torch.isfinite(e)).any(dim=1).nonzero().flatten().tolist()
        raise ValueError(f"embeddings contain NaN/Inf at items {bad[:10]}")
    e = torch.nn.functional.normalize(e, dim=1, eps=1e-12)
    return (e[queries][:, None, :] * e[candidates]).sum(-1)


@dataclass
class RetrievalReference:
    """The model-independent half of the benchmark: drawn candidates and their SSIM scores.

    Computed once per evaluation set and shared by every model scored on it.
    """

    queries: torch.Tensor      # (Q,) long dataset indices
    candidates: torch.Tensor   # (Q,C) long, rows ascending
    ssim: torch.Tensor         # (Q,C) float64 SSIM(query, candidate)
    skipped: int
    cfg: RetrievalConfig


def retrieval_reference(maps, episodes, frames, cfg: RetrievalConfig | None = None) -> RetrievalReference:
    """Draw candidates and score them by SSIM. maps (N,1,H,W) or (N,H,W) in [0,1]."""
    cfg = (cfg or RetrievalConfig()).validate()
    maps_t = torch.as_tensor(maps)
    if len(episodes) != maps_t.shape[0] or len(frames) != maps_t.shape[0]:
        raise ValueError(f"episodes/frames ({len(episodes)}/{len(frames)}) must match {maps_t.shape[0]} maps")
    queries, cands, skipped = draw_candidates(episodes, frames, cfg)
    q_t, c_t = torch.from_numpy(queries), torch.from_numpy(cands)
    if len(queries):
        used = np.unique(np.concatenate([queries, cands.ravel()]))     # stats only for maps in play
        pos = torch.full((maps_t.shape[0],), -1, dtype=torch.long)
        pos[torch.from_numpy(used)] = torch.arange(len(used))
        ref = ssim_query_candidates(map_stats(maps_t[torch.from_numpy(used)]), pos[q_t], pos[c_t], data_range=1.0)
    else:
        ref = torch.zeros(c_t.shape, dtype=torch.float64)
    return RetrievalReference(q_t, c_t, ref, skipped, cfg)


def mean_scores(reference: RetrievalReference, similarity: torch.Tensor) -> tuple[float, float]:
    """(Hit@1, Recall@k) means over the queries for a (Q,C) similarity matrix."""
    cfg = reference.cfg
    ref, sim = reference.ssim.numpy(), similarity.to(torch.float64).numpy()
    hits = [expected_top_k_score(r, e, 1, cfg.tie_tolerance) for r, e in zip(ref, sim)]
    recalls = [expected_top_k_score(r, e, cfg.top_k, cfg.tie_tolerance) for r, e in zip(ref, sim)]
    return float(np.mean(hits)), float(np.mean(recalls))


def score_retrieval(reference: RetrievalReference, embeddings) -> dict:
    """Hit@1 / Recall@k of an embedding against the SSIM reference, with chance levels
    (theoretical, constant embedding, shuffled embeddings; module doc).

    Values are None if no query could be formed (too few eligible maps).
    """
    cfg, k = reference.cfg, reference.cfg.top_k
    embeddings = torch.as_tensor(embeddings)
    scored = ("hit_at_1", f"recall_at_{k}")
    out = {"queries": int(len(reference.queries)), "skipped": reference.skipped,
           "num_candidates": cfg.num_candidates, "exclude_radius": cfg.exclude_radius,
           "tie_tolerance": cfg.tie_tolerance, "shuffle_rounds": cfg.shuffle_rounds,
           "chance_hit_at_1": 1.0 / cfg.num_candidates, f"chance_recall_at_{k}": k / cfg.num_candidates,
           **{f"{kind}{key}": None for kind in ("", "constant_", "shuffled_") for key in scored}}
    if embeddings.ndim != 2:
        raise ValueError(f"embeddings must be (N,E), got {tuple(embeddings.shape)}")
    if len(reference.queries) == 0:
        return out
    if int(reference.candidates.max()) >= embeddings.shape[0]:
        raise ValueError(f"embeddings has {embeddings.shape[0]} rows, the reference indexes "
                         f"{int(reference.candidates.max()) + 1}")
    q_t, c_t = reference.queries, reference.candidates
    out.update(zip(scored, mean_scores(reference, cosine_scores(embeddings, q_t, c_t))))
    out.update(zip((f"constant_{key}" for key in scored),
                   mean_scores(reference, torch.zeros(c_t.shape, dtype=torch.float64))))
    rng = np.random.default_rng(cfg.seed)
    rounds = [mean_scores(reference, cosine_scores(embeddings[torch.from_numpy(rng.permutation(len(embeddings)))],
                                                   q_t, c_t)) for _ in range(cfg.shuffle_rounds)]
    out.update(zip((f"shuffled_{key}" for key in scored), np.mean(rounds, axis=0).tolist()))
    return out


def retrieval_metrics(maps, embeddings, episodes, frames, cfg: RetrievalConfig | None = None) -> dict:
    """One-shot scoring: `retrieval_reference` then `score_retrieval`."""
    embeddings = torch.as_tensor(embeddings)
    n = torch.as_tensor(maps).shape[0]
    if embeddings.ndim != 2 or embeddings.shape[0] != n:
        raise ValueError(f"embeddings must be (N,E) with N = {n} maps, got {tuple(embeddings.shape)}")
    return score_retrieval(retrieval_reference(maps, episodes, frames, cfg), embeddings)
