import math

import pytest
import torch

from handtouch.masking import choose_parts, p_full, part_mask, sample_masks


def regions_map(b=4):
    """Six part bands plus an outside (0) border, like the canonical part map."""
    r = torch.zeros(b, 224, 224, dtype=torch.uint8)
    for part in range(1, 7):
        r[:, 10 + (part - 1) * 34: 10 + part * 34, 10:214] = part
    return r


def test_curriculum_exact_values():
    assert p_full(0.5, 0.1, 0.9) == pytest.approx(0.5, abs=1e-15)
    assert p_full(0.0, 0.1, 0.9) == pytest.approx(0.1 + 0.8 / (1 + math.exp(6)), abs=1e-15)
    assert p_full(1.0, 0.1, 0.9) == pytest.approx(0.1 + 0.8 / (1 + math.exp(-6)), abs=1e-15)
    assert p_full(0.0, 0.1, 0.9) == pytest.approx(0.101978, abs=1e-6)
    assert p_full(1.0, 0.1, 0.9) == pytest.approx(0.898022, abs=1e-6)
    assert p_full(0.3, 0.2, 0.2) == 0.2


def test_curriculum_rejects_progress_outside_unit_interval():
    for g in (-0.01, 1.01, float("nan")):
        with pytest.raises(ValueError):
            p_full(g, 0.1, 0.9)


def test_regional_mask_is_exactly_the_chosen_parts_pixels():
    regions = regions_map(64)
    gen = torch.Generator().manual_seed(0)
    mask, complete = sample_masks(regions, 0.0, 0.0, 0.0, max_parts=3, generator=gen)
    assert not complete.any()
    for i in range(64):
        hidden_parts = set(regions[i][mask[i, 0] > 0].unique().tolist())
        assert 0 not in hidden_parts and 1 <= len(hidden_parts) <= 3
        expected = torch.isin(regions[i], torch.tensor(sorted(hidden_parts), dtype=torch.uint8))
        assert torch.equal(mask[i, 0] > 0, expected)


def test_single_part_masks_cover_every_part():
    chosen = choose_parts(600, max_parts=1, generator=torch.Generator().manual_seed(1))
    assert not chosen[:, 0].any()
    assert torch.equal(chosen.sum(1), torch.ones(600, dtype=torch.long))
    assert set(chosen[:, 1:].float().argmax(1).add(1).tolist()) == {1, 2, 3, 4, 5, 6}


def test_complete_masks_hide_all_pixels():
    regions = regions_map(8)
    mask, complete = sample_masks(regions, 1.0, 1.0, 1.0, max_parts=2)
    assert complete.all()
    assert torch.equal(mask, torch.ones(8, 1, 224, 224))


def test_complete_fraction_follows_curriculum():
    regions = torch.zeros(4000, 4, 4, dtype=torch.uint8)
    gen = torch.Generator().manual_seed(2)
    for g in (0.0, 0.5, 1.0):
        _, complete = sample_masks(regions, g, 0.1, 0.9, max_parts=2, generator=gen)
        assert float(complete.float().mean()) == pytest.approx(p_full(g, 0.1, 0.9), abs=0.03)


def test_masks_are_reproducible_with_a_generator():
    regions = regions_map(6)
    a = sample_masks(regions, 0.3, 0.1, 0.9, 2, torch.Generator().manual_seed(5))
    b = sample_masks(regions, 0.3, 0.1, 0.9, 2, torch.Generator().manual_seed(5))
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_part_mask_rejects_unknown_part_ids_and_bad_shapes():
    chosen = torch.ones(1, 7, dtype=torch.bool)
    with pytest.raises(ValueError, match="part ids"):
        part_mask(torch.full((1, 4, 4), 7, dtype=torch.uint8), chosen)
    with pytest.raises(ValueError):
        part_mask(torch.zeros(4, 4, dtype=torch.uint8), chosen)
    with pytest.raises(ValueError):
        choose_parts(2, max_parts=0)


def test_without_the_curriculum_the_complete_share_stays_at_its_midpoint():
    """The "w/o drop" ablation: MaskingConfig.curriculum = False."""
    from handtouch.config import MaskingConfig, StageConfig
    from handtouch.stages import MASK, MaskedFusion, StepInfo

    regions = torch.zeros(400, 224, 224, dtype=torch.uint8)
    regions[:, :, :112] = 1
    batch = {"regions": regions}

    def complete_share(curriculum: bool, step: int) -> float:
        stage = MaskedFusion(StageConfig(trainable=["fusion"]), masking=MaskingConfig(0.0, 1.0, 1, curriculum))
        mask = stage.prepare(batch, StepInfo(step, 100))[MASK]
        return float((mask.flatten(1).min(1).values == 1).float().mean())

    assert complete_share(True, 0) < 0.05 and complete_share(True, 99) > 0.95     # the curriculum
    for step in (0, 99):
        assert 0.4 < complete_share(False, step) < 0.6                            # flat at p_full(0.5)
