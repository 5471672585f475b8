import numpy as np
import pytest
import torch

from handtouch.bench.retrieval import (RetrievalConfig, draw_candidates, eligible_candidates, rank,
                                       retrieval_metrics)


def _graded_set(n_noise=21, size=32, seed=0):
    """Map 0 = a base blob; maps 1..n = base + noise of strictly increasing strength.

    Both SSIM and cosine similarity to map 0 fall monotonically with the noise
    level, so a pixel embedding must agree with the SSIM ranking for query 0.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    base = np.exp(-((yy - 12) ** 2 + (xx - 18) ** 2) / 40.0)
    noise = rng.random((size, size))
    maps = [base] + [np.clip((1 - a) * base + a * noise, 0, 1) for a in np.linspace(0.05, 0.95, n_noise)]
    return np.array(maps, np.float32)


def test_eligible_excludes_query_and_episode_neighbours():
    episodes = np.array([0, 0, 0, 0, 1, 1])
    frames = np.array([0, 1, 2, 9, 0, 1])
    assert eligible_candidates(episodes, frames, 1, exclude_radius=1).tolist() == [3, 4, 5]
    assert eligible_candidates(episodes, frames, 1, exclude_radius=0).tolist() == [0, 2, 3, 4, 5]


def test_draw_is_seeded_sorted_and_skips_small_pools():
    episodes = np.arange(30) // 10
    frames = np.arange(30) % 10
    cfg = RetrievalConfig(num_candidates=20, exclude_radius=100, seed=3)
    q1, c1, skipped = draw_candidates(episodes, frames, cfg)
    q2, c2, _ = draw_candidates(episodes, frames, cfg)
    assert skipped == 0 and len(q1) == 30
    assert np.array_equal(c1, c2) and np.array_equal(q1, q2)
    assert (np.diff(c1, axis=1) > 0).all()
    for q, row in zip(q1, c1):
        assert not (episodes[row] == episodes[q]).any()   # whole episode excluded at radius 100
    # 3 episodes of 10 with 21 candidates: only 20 eligible -> every query skipped
    q, c, skipped = draw_candidates(episodes, frames, RetrievalConfig(num_candidates=21, exclude_radius=100))
    assert len(q) == 0 and skipped == 30 and c.shape == (0, 21)


def test_tie_break_lower_index_first():
    scores = torch.tensor([[0.5, 0.9, 0.9, 0.1]])
    cands = torch.tensor([[2, 5, 7, 8]])
    assert rank(scores, cands).tolist() == [[1, 2, 0, 3]]
    with pytest.raises(ValueError, match="sorted"):
        rank(scores, torch.tensor([[5, 2, 7, 8]]))


def _only_query_zero(n):
    """Items 1..n-1 share one episode and exclude each other (radius 100), so only
    item 0 has 20 eligible candidates; every other query is skipped."""
    episodes = np.r_[0, np.ones(n - 1, int)]
    frames = np.r_[0, np.arange(n - 1)]
    return episodes, frames, RetrievalConfig(num_candidates=n - 1, exclude_radius=100)


def test_oracle_pixel_embedding_agrees_and_reversed_disagrees():
    maps = _graded_set(n_noise=20)
    episodes, frames, cfg = _only_query_zero(len(maps))
    flat = torch.tensor(maps.reshape(len(maps), -1))
    good = retrieval_metrics(maps[:, None], flat, episodes, frames, cfg)
    assert good["queries"] == 1 and good["skipped"] == len(maps) - 1
    assert good["hit_at_1"] == 1.0 and good["recall_at_5"] == 1.0
    reversed_emb = -flat
    reversed_emb[0] = flat[0]                 # cos(q, -c) = -cos(q, c): the ranking flips
    worst = retrieval_metrics(maps, reversed_emb, episodes, frames, cfg)
    assert worst["hit_at_1"] == 0.0 and worst["recall_at_5"] == 0.0
    assert good["chance_hit_at_1"] == pytest.approx(0.05)
    assert good["chance_recall_at_5"] == pytest.approx(0.25)


def test_partial_recall_hand_computed():
    maps = _graded_set(n_noise=20)
    episodes, frames, cfg = _only_query_zero(len(maps))
    # embedding ranks candidates 1,2 first (agree), then 20,19,18 ...: top-5 overlap = {1,2}
    level = np.r_[0.0, np.arange(1, 21)].astype(np.float64)
    score = np.where(level <= 2, 100 - level, level)
    score[0] = 1000.0
    emb = torch.tensor(np.stack([np.ones_like(score), score], 1))
    # cosine to the query falls as score falls (vectors (1, s) with s > 0)
    res = retrieval_metrics(maps, emb, episodes, frames, cfg)
    assert res["hit_at_1"] == 1.0
    assert res["recall_at_5"] == pytest.approx(2 / 5)


def test_ties_constant_maps_and_zero_embeddings_never_nan():
    n = 21
    maps = np.zeros((n, 16, 16), np.float32)
    episodes, frames, cfg = _only_query_zero(n)
    res = retrieval_metrics(maps, torch.zeros(n, 4), episodes, frames, cfg)
    # all SSIM = 1 and all cosines = 0: both rankings fall back to dataset order -> agree
    assert res["hit_at_1"] == 1.0 and res["recall_at_5"] == 1.0
    with pytest.raises(ValueError, match="NaN"):
        retrieval_metrics(maps, torch.full((n, 4), float("nan")), episodes, frames, cfg)
    with pytest.raises(ValueError, match="embeddings"):
        retrieval_metrics(maps, torch.zeros(n - 1, 4), episodes, frames, cfg)


def test_random_embeddings_score_near_chance():
    rng = np.random.default_rng(5)
    maps = rng.random((160, 16, 16)).astype(np.float32)
    res = retrieval_metrics(maps, torch.tensor(rng.normal(size=(160, 8))), np.arange(160),
                            np.zeros(160, int), RetrievalConfig(seed=2))
    assert res["queries"] == 160
    assert res["hit_at_1"] < 0.15 and 0.1 < res["recall_at_5"] < 0.4


def test_no_possible_query_gives_none():
    res = retrieval_metrics(np.zeros((5, 8, 8)), torch.ones(5, 2), np.arange(5), np.zeros(5, int))
    assert res["hit_at_1"] is None and res["queries"] == 0 and res["skipped"] == 5
