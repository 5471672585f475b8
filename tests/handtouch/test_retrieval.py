import itertools
import math

import numpy as np
import pytest
import torch

from handtouch.bench.retrieval import (
    TIE_TOL,
    RetrievalConfig,
    draw_candidates,
    eligible_candidates,
    expected_top_k_score,
    retrieval_metrics,
    retrieval_reference,
    score_retrieval,
    top_k_split,
)
from handtouch.bench.ssim import ssim


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


def test_top_k_split_groups_ties_within_the_tolerance():
    scores = np.array([0.9, 0.5, 0.9 - TIE_TOL / 2, 0.7, 0.7, 0.7, 0.1])
    inside, straddling = top_k_split(scores, 3)
    assert inside.tolist() == [True, False, True, False, False, False, False]      # the 0.9 pair
    assert straddling.tolist() == [False, False, False, True, True, True, False]   # 0.7 x3 crosses 3rd place
    inside, straddling = top_k_split(scores, 5)                                     # a group ends at 5th place
    assert inside.sum() == 5 and not straddling.any()
    inside, straddling = top_k_split(np.array([0.9, 0.9 - 10 * TIE_TOL, 0.1]), 1)  # beyond tolerance: no tie
    assert inside.tolist() == [True, False, False] and not straddling.any()
    with pytest.raises(ValueError, match="k"):
        top_k_split(scores, 8)


def _brute_force(ref, emb, k):
    """Mean over every embedding tie order of the best top-k overlap over every SSIM tie order, / k."""
    perms = list(itertools.permutations(range(len(ref))))

    def orders(s):
        return [p for p in perms if all(s[a] >= s[b] for a, b in zip(p, p[1:]))]

    ssim_sets = {frozenset(p[:k]) for p in orders(ref)}
    emb_orders = orders(emb)
    return sum(max(len(set(p[:k]) & g) for g in ssim_sets) for p in emb_orders) / len(emb_orders) / k


def test_expected_score_equals_brute_force_over_tie_orders():
    rng = np.random.default_rng(0)
    for _ in range(120):
        c = int(rng.integers(2, 8))
        k = int(rng.integers(1, c + 1))
        ref = rng.integers(0, rng.integers(1, 4), c).astype(np.float64)   # heavy ties, often all tied
        emb = rng.integers(0, rng.integers(1, 4), c).astype(np.float64)
        assert expected_top_k_score(ref, emb, k) == pytest.approx(_brute_force(ref, emb, k), abs=1e-12)


def test_six_ssim_ties_and_a_constant_embedding_score_chance_not_one():
    """The issue's reproducer: six SSIM-tied best candidates at the lowest indices."""
    ref = np.r_[np.ones(6), np.linspace(0.5, 0.1, 14)]
    assert expected_top_k_score(ref, np.zeros(20), 1) == pytest.approx(6 / 20)        # |G| / C
    # |T & B| ~ Hypergeometric(20, 6, 5), need = 5 > |T & B| always: E = 5 * 6 / 20 = 1.5 -> 1.5 / 5
    assert expected_top_k_score(ref, np.zeros(20), 5) == pytest.approx(0.3)


def test_perfect_embedding_scores_one_with_ties_straddling_kth_place():
    ref = np.array([0.9, 0.8, 0.8, 0.7, 0.7, 0.7, 0.7, 0.2, 0.1, 0.1])     # 0.7 x4 crosses 5th place
    assert top_k_split(ref, 5)[1].sum() == 4
    for emb in (ref, 2 * ref - 5, np.exp(ref)):                             # same order, same ties
        assert expected_top_k_score(ref, emb, 5) == 1.0 and expected_top_k_score(ref, emb, 1) == 1.0
    # an embedding that orders inside the SSIM tie is just as right (any member of B fills the slots)
    assert expected_top_k_score(ref, ref + np.r_[0, 0, 0, 0.01, 0.02, 0.03, 0.04, 0, 0, 0], 5) == 1.0
    # an embedding that ties a wrong candidate into its top group is not perfect
    wrong = ref.copy()
    wrong[7] = 0.9
    assert expected_top_k_score(ref, wrong, 1) == pytest.approx(0.5)


def test_constant_embedding_scores_each_querys_chance_level():
    rng = np.random.default_rng(1)
    for _ in range(50):
        ref = rng.integers(0, 4, 20).astype(np.float64)
        g = int((ref == ref.max()).sum())
        assert expected_top_k_score(ref, np.full(20, 0.3), 1) == pytest.approx(g / 20)
    distinct = rng.permutation(20).astype(np.float64)
    assert expected_top_k_score(distinct, np.zeros(20), 5) == pytest.approx(0.25)     # 5/C without ties


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
    # all SSIM = 1: every candidate is an equally right answer, so any pick scores 1
    assert res["hit_at_1"] == 1.0 and res["recall_at_5"] == 1.0
    assert res["constant_hit_at_1"] == 1.0 and res["shuffled_recall_at_5"] == 1.0
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


def _contact_maps(n, size=16):
    """Maps with strictly increasing contact (a growing bright square): all SSIM-distinct."""
    maps = np.zeros((n, size, size), np.float32)
    for i in range(n):
        maps[i, 2:2 + (i % 12) + 1, 3:3 + i // 12 + 2] = 0.2 + 0.03 * i
    return maps


def test_reproducer_end_to_end_six_empty_candidates_at_the_lowest_indices():
    """Query 0 empty; candidates 1..6 empty (SSIM 1, lowest indices); 7..20 have contact.
    The old index tie-break gave a constant embedding Hit@1 = Recall@5 = 1.0."""
    maps = np.concatenate([np.zeros((7, 16, 16), np.float32), _contact_maps(14)])
    episodes, frames, cfg = _only_query_zero(len(maps))
    ref = retrieval_reference(maps, episodes, frames, cfg)
    assert ref.candidates[0].tolist() == list(range(1, 21))
    top = ref.ssim[0] >= ref.ssim[0].max() - TIE_TOL
    assert top.tolist() == [True] * 6 + [False] * 14
    res = score_retrieval(ref, torch.ones(len(maps), 3))
    assert res["hit_at_1"] == pytest.approx(0.3) and res["recall_at_5"] == pytest.approx(0.3)
    assert res["constant_hit_at_1"] == pytest.approx(0.3) and res["constant_recall_at_5"] == pytest.approx(0.3)
    assert res["chance_hit_at_1"] == 0.05 and res["chance_recall_at_5"] == 0.25      # theoretical, no ties


def test_end_to_end_perfect_embedding_with_exact_ssim_ties():
    """Embeddings whose cosine to the query IS the SSIM (2-D unit vectors at angle acos(SSIM)):
    three identical candidate maps tie across 5th place, and the embedding ties them too."""
    contact = _contact_maps(24)
    query, others = contact[23], contact[:23]
    by_ssim = others[np.argsort(-ssim(np.repeat(query[None], 23, 0), others, data_range=1.0).numpy())]
    # SSIM ranks 1-3, then the 4th-best map three times (places 4-6), then 14 more
    maps = np.concatenate([query[None], by_ssim[:3], by_ssim[3:4].repeat(3, 0), by_ssim[4:18]])
    episodes, frames, cfg = _only_query_zero(len(maps))
    ref = retrieval_reference(maps, episodes, frames, cfg)
    s = ref.ssim[0].numpy()
    assert top_k_split(s, 5)[1].sum() == 3                    # the 3 identical maps straddle 5th place
    emb = np.zeros((len(maps), 2))
    emb[0] = (1.0, 0.0)
    emb[1:] = np.stack([s, np.sqrt(1 - s ** 2)], 1)
    res = score_retrieval(ref, torch.tensor(emb))
    assert res["hit_at_1"] == 1.0 and res["recall_at_5"] == 1.0
    # constant: S = 3 sure, B = the 3 tied with need 2; |T & S| ~ 5 * 3/20 on average and
    # E[min(2, X)] = E[X] - P(X = 3) for X ~ Hypergeometric(20, 3, 5)
    chance = (5 * 3 / 20 + 5 * 3 / 20 - math.comb(17, 2) / math.comb(20, 5)) / 5
    assert res["constant_hit_at_1"] == pytest.approx(0.05) and res["constant_recall_at_5"] == pytest.approx(chance)
    assert chance > 0.25                                      # ties straddling 5th place raise chance
    assert res["shuffled_hit_at_1"] < 1.0 and res["shuffled_recall_at_5"] < 1.0


def test_shuffled_chance_is_seeded_and_averaged():
    rng = np.random.default_rng(4)
    maps = rng.random((60, 16, 16)).astype(np.float32)
    emb = torch.tensor(rng.normal(size=(60, 4)))
    cfg = RetrievalConfig(seed=1, shuffle_rounds=3)
    a = retrieval_metrics(maps, emb, np.arange(60), np.zeros(60, int), cfg)
    b = retrieval_metrics(maps, emb, np.arange(60), np.zeros(60, int), cfg)
    assert a == b and a["shuffle_rounds"] == 3
    assert 0.0 <= a["shuffled_hit_at_1"] <= 0.2 and 0.1 <= a["shuffled_recall_at_5"] <= 0.4
    assert a["constant_hit_at_1"] == pytest.approx(0.05)       # random maps: no SSIM ties
    with pytest.raises(ValueError, match="shuffle_rounds"):
        RetrievalConfig(shuffle_rounds=0).validate()


def test_expected_score_rejects_mismatched_or_non_finite_scores():
    with pytest.raises(ValueError, match="differ in shape"):
        expected_top_k_score(np.zeros(20), np.zeros(19), 5)
    with pytest.raises(ValueError, match="NaN"):
        expected_top_k_score(np.r_[np.nan, np.zeros(19)], np.zeros(20), 5)
