import math

import pytest
import torch

from handtouch.vq import FactorisedVQ


def make_vq(k=16, d=4, dim=8, tau=1.0, decay=0.9, noise=0.01, seed=0):
    torch.manual_seed(seed)
    return FactorisedVQ(dim, d, k, beta=0.25, dead_threshold=tau, usage_decay=decay, restart_noise=noise)


def test_first_training_step_restarts_every_code_from_batch_features():
    vq = make_vq(k=16, noise=1e-3)
    z_e = torch.randn(4, 32, 8)
    _, _, _, stats = vq(z_e)
    assert stats["restarts"] == 16
    feats = vq.w_in(z_e).reshape(-1, 4).detach()
    # every code sits within the restart noise of some projected batch feature
    dist = torch.cdist(vq.codebook.detach(), feats).min(dim=1).values
    assert float(dist.max()) < 1e-3 * 4 * 5


def test_restart_replaces_exactly_the_dead_codes():
    vq = make_vq(k=16)
    vq(torch.randn(4, 32, 8))                      # initialise from data
    vq.usage.fill_(10.0)
    dead = torch.tensor([1, 5, 9])
    vq.usage[dead] = 0.0
    before = vq.codebook.detach().clone()
    _, _, _, stats = vq(torch.randn(4, 32, 8))
    assert stats["restarts"] == 3
    changed = (vq.codebook.detach() != before).any(dim=1)
    assert changed.nonzero().flatten().tolist() == dead.tolist()
    # restarted codes get a grace period above the threshold
    assert bool((vq.usage[dead] >= vq.dead_threshold).all())


def test_no_restart_in_eval_mode_and_usage_frozen():
    vq = make_vq(k=16).eval()
    before = vq.codebook.detach().clone()
    _, _, _, stats = vq(torch.randn(2, 16, 8))
    assert stats["restarts"] == 0
    assert torch.equal(vq.codebook.detach(), before)
    assert float(vq.usage.sum()) == 0.0


def test_unused_code_goes_dead_then_restarts():
    vq = make_vq(k=8, tau=1.0, decay=0.5)
    vq(torch.randn(2, 64, 8))
    vq.usage.fill_(100.0)
    vq.codebook.data[3] = 1e6                      # unreachable: never chosen
    restarted_at = None
    for step in range(30):
        _, _, _, stats = vq(torch.randn(2, 64, 8))
        if float(vq.codebook.detach()[3].abs().max()) < 1e5:
            restarted_at = step
            break
    assert restarted_at is not None and restarted_at > 2   # needs the EMA to decay first


def test_straight_through_gradient_reaches_encoder():
    torch.manual_seed(1)
    encoder = torch.nn.Linear(5, 8)
    vq = make_vq()
    x = torch.randn(2, 10, 5)
    z_out, idx, losses, _ = vq(encoder(x))
    (z_out.pow(2).sum() + losses["commit"]).backward()
    assert encoder.weight.grad is not None and float(encoder.weight.grad.abs().sum()) > 0
    assert float(vq.w_in.weight.grad.abs().sum()) > 0
    assert idx.shape == (2, 10) and idx.dtype == torch.long


def test_codebook_loss_trains_the_codebook_only_through_chosen_codes():
    vq = make_vq(k=16)
    vq(torch.randn(2, 8, 8))
    vq.zero_grad()
    _, idx, losses, _ = vq(torch.randn(2, 8, 8))
    losses["codebook"].backward()
    has_grad = vq.codebook.grad.abs().sum(dim=1) > 0
    assert set(has_grad.nonzero().flatten().tolist()) <= set(idx.flatten().tolist())
    assert vq.w_in.weight.grad is None or float(vq.w_in.weight.grad.abs().sum()) == 0.0


def test_float32_inside_bf16_autocast():
    vq = make_vq()
    z_e = torch.randn(2, 16, 8)
    with torch.autocast(device_type="cpu", dtype=torch.bfloat16):
        h = torch.nn.functional.linear(z_e, torch.eye(8))      # a bf16 activation
        assert h.dtype == torch.bfloat16
        z_out, _, losses, stats = vq(h)
    assert z_out.dtype == torch.float32
    assert losses["codebook"].dtype == torch.float32 and losses["commit"].dtype == torch.float32
    assert torch.isfinite(stats["perplexity"])


def test_all_zero_input_is_finite():
    vq = make_vq(noise=0.0)
    for _ in range(3):
        z_out, idx, losses, stats = vq(torch.zeros(2, 16, 8))
    assert torch.isfinite(z_out).all()
    assert all(torch.isfinite(v) for v in losses.values())
    assert all(torch.isfinite(v) for v in stats.values())
    assert float(stats["perplexity"]) == pytest.approx(1.0)


def test_perplexity_and_usage_of_a_known_assignment():
    vq = make_vq(k=8, d=4).eval()
    with torch.no_grad():
        vq.w_in.weight.zero_()
        vq.w_in.weight[:, :4] = torch.eye(4)
        vq.w_in.bias.zero_()
        vq.codebook.zero_()
        vq.codebook[:4] = torch.eye(4) * 10
    # 4 codes used equally often -> perplexity 4, usage 4/8
    z = torch.zeros(1, 8, 8)
    z[0, torch.arange(8), torch.arange(8) % 4] = 10.0
    _, idx, _, stats = vq(z)
    assert idx.flatten().tolist() == [0, 1, 2, 3, 0, 1, 2, 3]
    assert float(stats["perplexity"]) == pytest.approx(4.0, rel=1e-5)
    assert float(stats["usage"]) == pytest.approx(0.5)
    assert math.isclose(float(stats["restarts"]), 0.0)
