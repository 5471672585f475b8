"""HT-Bench 1-vs-20 tactile retrieval.

Protocol (per query map q of the evaluation set):
- Candidates: `num_candidates` (20) maps drawn without replacement by a
  seeded RNG from the evaluation set, EXCLUDING q itself and every frame of
  q's episode within +-`exclude_radius` frames (neighbouring frames are near
  duplicates and would make the task trivial). A query with fewer eligible
  maps than `num_candidates` is skipped and counted.
- Reference ranking: SSIM(q, candidate) (skimage defaults, data_range 1).
- Model ranking: cosine similarity of the model's embeddings.
- Ties: both rankings use a stable sort on (-score, candidate dataset
  index), i.e. equal scores rank the lower dataset index first.
- Hit@1: the SSIM-nearest candidate is ranked first by the embedding.
- Recall@5: |SSIM top-5 & embedding top-5| / 5.
- Chance: Hit@1 = 1/C, Recall@5 = 5/C (expected overlap of two random
  5-subsets of C is 25/C items).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from handtouch.bench.ssim import map_stats, ssim_query_candidates


@dataclass
class RetrievalConfig:
    num_candidates: int = 20
    top_k: int = 5
    exclude_radius: int = 5      # same-episode frames within +-radius of the query are never candidates
    max_queries: int | None = None
    seed: int = 0

    def validate(self) -> "RetrievalConfig":
        if self.num_candidates < 1:
            raise ValueError(f"num_candidates must be >= 1, got {self.num_candidates}")
        if not 1 <= self.top_k <= self.num_candidates:
            raise ValueError(f"top_k must be in [1, num_candidates], got {self.top_k}")
        if self.exclude_radius < 0:
            raise ValueError(f"exclude_radius must be >= 0, got {self.exclude_radius}")
        if self.max_queries is not None and self.max_queries < 1:
            raise ValueError(f"max_queries must be >= 1 or None, got {self.max_queries}")
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


def rank(scores: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """Positions (into each row) ordered best first: stable sort by (-score, candidate index).

    Rows of `candidates` are sorted ascending, so a stable sort on -score
    alone already breaks ties by the lower dataset index.
    """
    if not bool((candidates[:, 1:] > candidates[:, :-1]).all()):
        raise ValueError("candidate rows must be sorted ascending for the tie-break rule")
    return torch.sort(-scores.to(torch.float64), dim=1, stable=True).indices


def cosine_scores(embeddings: torch.Tensor, queries: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """(Q,C) cosine similarity; zero-norm embeddings give 0 similarity, never NaN."""
    e = embeddings.to(torch.float64)
    if not torch.isfinite(e).all():
        bad = (~torch.isfinite(e)).any(dim=1).nonzero().flatten().tolist()
        raise ValueError(f"embeddings contain NaN/Inf at items {bad[:10]}")
    e = torch.nn.functional.normalize(e, dim=1, eps=1e-12)
    return torch.einsum("qe,qce->qc", e[queries], e[candidates])


@dataclass
class RetrievalReference:
    """The model-independent half of the benchmark: drawn candidates and their SSIM ranking.

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


def score_retrieval(reference: RetrievalReference, embeddings) -> dict:
    """Hit@1 / Recall@k of an embedding against the SSIM reference, with chance levels.

    Values are None if no query could be formed (too few eligible maps).
    """
    cfg, k = reference.cfg, reference.cfg.top_k
    embeddings = torch.as_tensor(embeddings)
    out = {"hit_at_1": None, f"recall_at_{k}": None, "queries": int(len(reference.queries)),
           "skipped": reference.skipped, "num_candidates": cfg.num_candidates,
           "exclude_radius": cfg.exclude_radius, "chance_hit_at_1": 1.0 / cfg.num_candidates,
           f"chance_recall_at_{k}": k / cfg.num_candidates}
    if embeddings.ndim != 2:
        raise ValueError(f"embeddings must be (N,E), got {tuple(embeddings.shape)}")
    if len(reference.queries) == 0:
        return out
    if int(reference.candidates.max()) >= embeddings.shape[0]:
        raise ValueError(f"embeddings has {embeddings.shape[0]} rows, the reference indexes "
                         f"{int(reference.candidates.max()) + 1}")
    q_t, c_t, ref = reference.queries, reference.candidates, reference.ssim
    emb = cosine_scores(embeddings, q_t, c_t)
    ref_rank, emb_rank = rank(ref, c_t), rank(emb, c_t)
    hits = (ref_rank[:, 0] == emb_rank[:, 0]).double()
    ref_top = torch.zeros(ref.shape, dtype=torch.bool).scatter_(1, ref_rank[:, :k], True)
    emb_top = torch.zeros(ref.shape, dtype=torch.bool).scatter_(1, emb_rank[:, :k], True)
    out["hit_at_1"] = float(hits.mean())
    out[f"recall_at_{k}"] = float(((ref_top & emb_top).sum(1).double() / k).mean())
    return out


def retrieval_metrics(maps, embeddings, episodes, frames, cfg: RetrievalConfig | None = None) -> dict:
    """One-shot scoring: `retrieval_reference` then `score_retrieval`."""
    embeddings = torch.as_tensor(embeddings)
    n = torch.as_tensor(maps).shape[0]
    if embeddings.ndim != 2 or embeddings.shape[0] != n:
        raise ValueError(f"embeddings must be (N,E) with N = {n} maps, got {tuple(embeddings.shape)}")
    return score_retrieval(retrieval_reference(maps, episodes, frames, cfg), embeddings)
