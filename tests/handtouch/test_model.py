import pytest
import torch

from handtouch.config import MODULE_NAMES, LossConfig, StageConfig
from handtouch.model import HandTouch, masked_mse
from handtouch.rgb_encoder import SmallConvRGB, load_rgb_encoder, model_rgb_features
from handtouch.stages import MASK, STAGES
from tests.factories.model import STAGE_TRAINABLE, frame_batch, make_stage, tiny_cfg, tiny_model


def stage_losses(model, n, batch, mask=None, weights=None):
    """{"loss", its terms, VQ stats}: stage n's loss on a batch, as the trainer computes it."""
    if mask is not None:
        batch = {**batch, MASK: mask}
    loss, terms = make_stage(n, weights).loss(model, batch)
    return {"loss": loss, **terms}


def window_batch(b=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {"tactile": torch.rand(b, 3, 1, 224, 224, generator=g), "coverage": torch.ones(b, 1, 224, 224),
            "rgb": torch.randint(0, 256, (b, 3, 3, 224, 224), generator=g, dtype=torch.uint8),
            "hand": torch.ones(b, dtype=torch.long)}


@pytest.mark.parametrize("encoder", ["vit", "cnn", "resnet18", "vqvae", "vit_plain"])
def test_api_shapes_for_every_encoder(encoder):
    model = tiny_model(encoder).eval()
    b = frame_batch(2)
    cov = torch.zeros(2, 1, 224, 224)
    cov[:, :, 50:150, 30:200] = 1
    mask = torch.zeros(2, 1, 224, 224)
    mask[:, :, :100] = 1
    w = window_batch(2)
    with torch.no_grad():
        tokens = model.encode(b["tactile"])
        assert tokens.shape == (2, model.cfg.num_tokens, 32)
        assert model.embed(b["tactile"], cov, b["hand"]).shape == (2, 32)
        outs = [model.reconstruct(b["tactile"], cov),
                model.inpaint(b["tactile"], cov, mask, b["rgb"], b["hand"]),
                model.rgb_to_tactile(b["rgb"], cov, b["hand"]),
                model.predict_next(w["rgb"], w["tactile"][:, :2], cov, w["hand"])]
    for out in outs:
        assert out.shape == (2, 1, 224, 224)
        assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
        assert float(out[cov == 0].abs().max()) == 0.0       # nothing predicted where there is no sensor
    assert model.name == {"vit": "handtouch-vit", "cnn": "baseline-cnn", "resnet18": "baseline-resnet18",
                          "vqvae": "baseline-vqvae", "vit_plain": "baseline-vit"}[encoder]


@pytest.mark.parametrize("stage", [1, 2, 3])
def test_losses_ignore_uncovered_pixels(stage):
    model = tiny_model().eval()       # eval: no VQ restarts, so two calls are comparable
    cov = torch.zeros(2, 1, 224, 224)
    cov[:, :, 40:180, 40:180] = 1
    if stage == 3:
        batch = window_batch(2)
        batch["coverage"] = cov
    else:
        batch = frame_batch(2, coverage=cov)
    mask = torch.zeros(2, 1, 224, 224)
    mask[:, :, :112] = 1
    with torch.no_grad():
        ref = stage_losses(model, stage, batch, mask)
        noisy = dict(batch)
        junk = torch.where(cov.bool(), torch.zeros(()), torch.full((), float("nan")))
        noisy["tactile"] = batch["tactile"] + (junk[:, None] if stage == 3 else junk)
        out = stage_losses(model, stage, noisy, mask)
    for key in ref:
        assert torch.isfinite(out[key]).all(), key
        assert torch.allclose(ref[key], out[key]), key


def test_masked_mse_zero_over_zero_and_nan_outside():
    pred = torch.rand(1, 1, 4, 4, requires_grad=True)
    target = torch.full((1, 1, 4, 4), float("nan"))
    loss = masked_mse(pred, target, torch.zeros(1, 1, 4, 4))
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.isfinite(pred.grad).all()
    weight = torch.zeros(1, 1, 4, 4)
    weight[..., 0, 0] = 1
    target = torch.zeros(1, 1, 4, 4)
    assert float(masked_mse(pred, target, weight).detach()) == pytest.approx(float(pred.detach()[0, 0, 0, 0]) ** 2)


def test_stage2_weights_visible_and_masked_terms():
    model = tiny_model().eval()
    b = frame_batch(2)
    mask = torch.zeros(2, 1, 224, 224)
    mask[:, :, :112] = 1
    w = LossConfig(lambda_vis=0.25, lambda_mask=2.0, vq_weight=0.0, lambda_replay=0.5)
    with torch.no_grad():
        out = stage_losses(model, 2, b, mask, w)
        full = stage_losses(model, 2, b, torch.ones_like(mask), w)
    assert float(out["loss"]) == pytest.approx(
        0.25 * float(out["visible"]) + 2.0 * float(out["masked"]) + 0.5 * float(out["replay"]), rel=1e-5)
    assert float(full["visible"]) == 0.0          # complete masking: nothing visible, 0/0 guarded
    with pytest.raises(ValueError, match="mask"):
        stage_losses(model, 2, b)


def _replay_weights(stage, weight):
    """LossConfig with the replay weight of `stage` (stage 2: lambda_replay; stage 3: the opt-in stage3_replay)."""
    if stage == 3:
        return LossConfig(vq_weight=0.0, stage3_replay=weight)
    return LossConfig(vq_weight=0.0, lambda_replay=weight)


@pytest.mark.parametrize("stage", [2, 3])
def test_replay_term_is_stage1_reconstruction(stage):
    """Stage 2 (and stage 3 when opted in) replay reconstruction (whole map / t_T through
    encoder -> VQ -> decoder); stage 3 by default is the next-frame term alone."""
    model = tiny_model().eval()
    cov = torch.zeros(2, 1, 224, 224)
    cov[:, :, 30:200, 20:190] = 1
    if stage == 3:
        batch = window_batch(2)
        batch["coverage"] = cov
        target = batch["tactile"][:, -1]
    else:
        batch = frame_batch(2, coverage=cov)
        target = batch["tactile"]
    mask = torch.zeros(2, 1, 224, 224)
    mask[:, :, :100] = 1
    with torch.no_grad():
        out = stage_losses(model, stage, batch, mask, _replay_weights(stage, 0.0))
        weighted = stage_losses(model, stage, batch, mask, _replay_weights(stage, 3.0))
        recon = masked_mse(model.reconstruct(target, cov), target * cov, cov)
    assert float(weighted["replay"]) == pytest.approx(float(recon), rel=1e-5)
    if stage == 2:
        assert float(out["replay"]) == pytest.approx(float(recon), rel=1e-5)   # logged at weight 0 too
    else:
        assert "replay" not in out                                           # not even computed
    assert float(weighted["loss"] - out["loss"]) == pytest.approx(3.0 * float(recon), rel=1e-4)
    if stage == 3:
        assert float(out["loss"]) == pytest.approx(float(out["next"]), rel=1e-6)
        with torch.no_grad():
            pred = model.predict_next(batch["rgb"], batch["tactile"][:, :2], cov, batch["hand"])
        assert float(out["next"]) == pytest.approx(float(masked_mse(pred, target * cov, cov)), rel=1e-5)


def test_all_zero_inputs_train_without_nan():
    model = tiny_model().train()
    b = frame_batch(2)
    b["tactile"].zero_()
    b["rgb"].zero_()
    out = stage_losses(model, 2, b, torch.zeros(2, 1, 224, 224))
    out["loss"].backward()
    assert torch.isfinite(out["loss"])
    for name, p in model.named_parameters():
        if p.grad is not None:
            assert torch.isfinite(p.grad).all(), name


@pytest.mark.parametrize("stage", [1, 2, 3])
def test_stage_freezing_freezes_exactly_the_named_parts(stage):
    model = tiny_model().train()
    make_stage(stage).configure(model)
    assert model.frozen == set(MODULE_NAMES) - set(STAGE_TRAINABLE[stage]) == set(make_stage(stage).frozen)
    batch = window_batch(2) if stage == 3 else frame_batch(2)
    out = stage_losses(model, stage, batch, torch.zeros(2, 1, 224, 224))
    out["loss"].backward()
    unused = {id(model.vq.codebook)} if stage == 3 else set()     # the paper's stage-3 loss has no VQ terms
    for name in MODULE_NAMES:
        params = [p for p in getattr(model, name).parameters() if id(p) not in unused]
        trainable = name in STAGE_TRAINABLE[stage]
        assert all(p.requires_grad == trainable for p in params), name
        if trainable:   # every trained module is used by this stage's loss
            assert any(p.grad is not None and float(p.grad.abs().sum()) > 0 for p in params), name
        else:
            assert all(p.grad is None for p in params), name
    assert not any(p.requires_grad for p in model.rgb_encoder.parameters())
    assert all(not getattr(model, n).training for n in model.frozen)
    assert not model.rgb_encoder.training


def test_freeze_unfreeze_by_name_and_unknown_names():
    model = tiny_model().train()
    model.freeze(["encoder"])
    assert not any(p.requires_grad for p in model.encoder.parameters())
    model.train()
    assert not model.encoder.training and model.decoder.training
    model.unfreeze(["encoder"])
    assert all(p.requires_grad for p in model.encoder.parameters()) and model.encoder.training
    with pytest.raises(ValueError, match="unknown module"):
        model.freeze(["rgb_encoder"])
    with pytest.raises(ValueError, match="unknown module"):
        model.set_trainable(["encodr"])


def test_stage3_encoder_frozen_gets_no_gradient():
    model = tiny_model().train()
    model.set_trainable(STAGE_TRAINABLE[3])
    out = stage_losses(model, 3, window_batch(2))
    out["loss"].backward()
    assert all(p.grad is None for p in model.encoder.parameters())
    with pytest.raises(ValueError, match="window"):
        stage_losses(model, 3, frame_batch(2))


def test_rgb_encoder_specs(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_rgb_encoder(str(tmp_path / "missing.pt2"))
    with pytest.raises(ValueError):
        load_rgb_encoder("random:abc")
    a, b = load_rgb_encoder("random:3"), load_rgb_encoder("random:3")
    rgb = torch.randint(0, 256, (2, 3, 224, 224), dtype=torch.uint8)
    assert torch.equal(a(rgb), b(rgb))
    assert not torch.equal(a(rgb), load_rgb_encoder("random:4")(rgb))
    assert torch.allclose(a(rgb), a(rgb.float() / 255))     # uint8 and [0,1] floats agree

    torch.manual_seed(0)
    net = SmallConvRGB()
    path = tmp_path / "enc.pt"
    torch.save({"arch": "small_conv", "state_dict": net.state_dict()}, path)
    enc = load_rgb_encoder(str(path))
    assert enc.info.kind == "state_dict" and len(enc.info.sha256) == 64
    assert not any(p.requires_grad for p in enc.parameters())
    assert torch.allclose(enc(rgb), net(rgb.float() / 255).flatten(2).transpose(1, 2))
    torch.save({"arch": "nope", "state_dict": {}}, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="unknown arch"):
        load_rgb_encoder(str(tmp_path / "bad.pt"))


def test_rgb_encoder_from_torch_export(tmp_path):
    net = SmallConvRGB().eval()
    ep = torch.export.export(net, (torch.rand(2, 3, 224, 224),),
                             dynamic_shapes=({0: torch.export.Dim("batch")},))
    path = tmp_path / "enc.pt2"
    torch.export.save(ep, str(path))
    enc = load_rgb_encoder(str(path))
    assert enc.info.kind == "export"
    rgb = torch.randint(0, 256, (3, 3, 224, 224), dtype=torch.uint8)
    assert torch.allclose(enc(rgb), net(rgb.float() / 255).flatten(2).transpose(1, 2), atol=1e-5)
    model = HandTouch(tiny_cfg(), enc)
    model.train()                       # must not call train() on the exported module
    assert model.rgb_to_tactile(rgb, torch.ones(3, 1, 224, 224), torch.zeros(3, dtype=torch.long)).shape == (3, 1, 224, 224)


def test_model_config_validation():
    with pytest.raises(ValueError):
        tiny_cfg(encoder="vgg").validate()
    with pytest.raises(ValueError):
        tiny_cfg(patch=14).validate()        # 224/14 = 16 tokens a side: not a doubling of 224
    with pytest.raises(ValueError):
        tiny_cfg(dim=30, heads=4).validate()
    with pytest.raises(ValueError, match="cnn_widths"):
        tiny_cfg(encoder="cnn", cnn_widths=[32, 64]).validate()
    with pytest.raises(ValueError, match="cnn_widths"):
        tiny_cfg(encoder="cnn", cnn_widths=[12, 64, 128]).validate()    # GroupNorm(8) needs multiples of 8
    with pytest.raises(ValueError, match="resnet_widths"):
        tiny_cfg(encoder="resnet18", resnet_widths=[16, 32, 0, 128]).validate()
    with pytest.raises(ValueError, match="lambda_replay"):
        LossConfig(lambda_replay=-1.0).validate()


@pytest.mark.parametrize("encoder,widths", [("cnn", {"cnn_widths": [8, 16, 24]}),
                                            ("resnet18", {"resnet_widths": [8, 16, 24, 32]})])
def test_baseline_widths_come_from_the_config(encoder, widths):
    model = tiny_model(encoder, **widths).eval()
    convs = [m for m in model.encoder.modules() if isinstance(m, torch.nn.Conv2d)]
    assert max(c.out_channels for c in convs) == list(widths.values())[0][-1]
    if encoder == "cnn":          # stride-4 stem: no conv runs at full 224x224 resolution
        assert convs[0].stride == (4, 4)
    with torch.no_grad():
        assert model.encode(torch.rand(2, 1, 224, 224)).shape == (2, model.cfg.num_tokens, 32)


def test_bf16_autocast_training_step_is_finite():
    model = tiny_model().train()
    b = frame_batch(2)
    with torch.autocast(device_type="cpu", dtype=torch.bfloat16):
        out = stage_losses(model, 2, b, torch.zeros(2, 1, 224, 224))
    assert out["loss"].dtype == torch.float32
    out["loss"].backward()
    assert torch.isfinite(out["loss"])
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_ablation_without_codebook_uses_the_continuous_latent():
    model = tiny_model(codebook=False).eval()
    b = frame_batch()
    tokens = model.encode(b["tactile"])
    pred, idx, losses, stats = model.quantise_decode(tokens, b["coverage"])
    assert torch.equal(pred, model.decoder(tokens) * b["coverage"])          # no quantisation in between
    assert float(losses["codebook"] + losses["commit"]) == 0.0 and torch.isnan(stats["perplexity"])
    assert (idx == 0).all()
    with_vq = tiny_model().eval()
    assert not torch.equal(with_vq.quantise_decode(tokens, b["coverage"])[0], with_vq.decoder(tokens) * b["coverage"])
    loss, _ = make_stage(1).loss(model.train(), b)
    loss.backward()
    assert all(p.grad is None for p in model.vq.parameters())               # the VQ is bypassed entirely


def test_ablation_without_vision_ignores_the_rgb_frame():
    b, other = frame_batch(seed=0), frame_batch(seed=1)
    blind, seeing = tiny_model(vision=False).eval(), tiny_model().eval()
    for model, same in ((blind, True), (seeing, False)):
        a = model.rgb_to_tactile(b["rgb"], b["coverage"], b["hand"])
        c = model.rgb_to_tactile(other["rgb"], b["coverage"], b["hand"])
        assert torch.equal(a, c) == same
        window = torch.stack([b["rgb"]] * 3, 1), torch.stack([other["rgb"]] * 3, 1)
        past = torch.stack([b["tactile"]] * 2, 1)
        p1, p2 = (model.predict_next(w, past, b["coverage"], b["hand"]) for w in window)
        assert torch.equal(p1, p2) == same


# ---- the encoder baselines and the design switches ---------------------------------------

def _attention_modules(module):
    return [m for m in module.modules() if isinstance(m, torch.nn.MultiheadAttention)]


def test_vqvae_baseline_is_a_conv_autoencoder_with_the_codebook():
    from handtouch.decoder import TactileDecoder
    from handtouch.encoders import VQVAEEncoder

    model = tiny_model("vqvae").train()
    assert isinstance(model.encoder, VQVAEEncoder) and isinstance(model.decoder, TactileDecoder)
    assert model.decoder.mixer == "conv"
    assert not _attention_modules(model.encoder) and not _attention_modules(model.decoder)
    assert _attention_modules(tiny_model("vit").decoder)            # HandTouch's decoder attends
    b = frame_batch(2)
    out = stage_losses(model, 1, b)
    assert float(out["vq"].detach()) > 0 and torch.isfinite(out["perplexity"])   # the latent is quantised
    out["loss"].backward()
    assert model.vq.codebook.grad is not None and float(model.vq.codebook.grad.abs().sum()) > 0


def test_plain_vit_baseline_has_no_codebook_and_a_linear_pixel_head():
    from handtouch.decoder import LinearPatchDecoder
    from handtouch.encoders import ViTEncoder

    model = tiny_model("vit_plain").train()
    assert isinstance(model.encoder, ViTEncoder) and isinstance(model.decoder, LinearPatchDecoder)
    assert not model.cfg.quantised and tiny_cfg("vit").quantised
    b = frame_batch(2)
    tokens = model.encode(b["tactile"])
    pred, _, losses, _ = model.eval().quantise_decode(tokens, b["coverage"])
    assert torch.equal(pred, model.decoder(tokens) * b["coverage"])     # no quantisation in between
    out = stage_losses(model.train(), 1, b)
    assert float(out["vq"]) == 0.0
    out["loss"].backward()
    assert all(p.grad is None for p in model.vq.parameters())
    # each token decodes its own 7x7-patch grid cell (patch 32): changing token 0 moves only that patch
    moved = tokens.clone()
    moved[:, 0] += 1.0
    diff = (model.decoder(moved) - model.decoder(tokens)).abs()[0, 0]
    assert float(diff[:32, :32].sum()) > 0 and float(diff[32:].sum() + diff[:, 32:].sum()) == 0.0


@pytest.mark.parametrize("encoder", ["cnn", "resnet18", "vqvae", "vit_plain"])
@pytest.mark.parametrize("stage", [1, 2, 3])
def test_baselines_freeze_by_module_name(encoder, stage):
    model = tiny_model(encoder, cnn_widths=[8, 16, 24], resnet_widths=[8, 16, 24, 32],
                       vqvae_widths=[8, 16, 24]).train()
    make_stage(stage).configure(model)
    assert model.frozen == set(MODULE_NAMES) - set(STAGE_TRAINABLE[stage])
    batch = window_batch(2) if stage == 3 else frame_batch(2)
    out = stage_losses(model, stage, batch, torch.zeros(2, 1, 224, 224))
    out["loss"].backward()
    for name in MODULE_NAMES:
        for p in getattr(model, name).parameters():
            # DDP's contract: a parameter is trainable exactly when this stage's loss gives it a gradient
            assert p.requires_grad == (p.grad is not None), name
            assert not p.requires_grad or name in STAGE_TRAINABLE[stage], name
    for name in ("encoder", "decoder") if stage < 3 else ("decoder", "predictor"):
        assert any(p.grad is not None and float(p.grad.abs().sum()) > 0
                   for p in getattr(model, name).parameters()), name


def test_mask_channel_switch_changes_the_encoder_input():
    one, two = tiny_model(), tiny_model(mask_channel=True)          # the paper's 1 channel is the default
    assert two.encoder.patch_embed.in_channels == 2 and one.encoder.patch_embed.in_channels == 1
    assert tiny_model("cnn").encoder.features[0].in_channels == 1
    b = frame_batch(2)
    mask = torch.zeros(2, 1, 224, 224)
    mask[:, :, :112] = 1
    hidden = b["tactile"] * (1 - mask)
    with torch.no_grad():
        # one channel: the mask acts only by zeroing; hiding pixels = showing zeros there
        assert torch.equal(one.encode(b["tactile"], mask), one.encode(hidden))
        # two channels: the model is told which zeros are hidden
        assert not torch.equal(two.encode(b["tactile"], mask), two.encode(hidden))
    with pytest.raises(ValueError, match="mask_channel"):
        tiny_cfg(mask_channel=1).validate()


def test_stage3_is_the_papers_loss_unless_replay_and_vq_terms_opt_in():
    batch = window_batch(2)
    model = tiny_model().train()
    make_stage(3).configure(model)
    assert not model.vq.codebook.requires_grad and model.vq.w_in.weight.requires_grad
    paper = stage_losses(model, 3, batch)
    assert set(paper) == {"loss", "vq", "next", "perplexity", "usage", "restarts"}
    assert float(paper["vq"]) > 0 and float(paper["loss"]) == pytest.approx(float(paper["next"]), rel=1e-6)
    paper["loss"].backward()
    assert model.vq.codebook.grad is None                  # only the VQ terms move the codebook
    assert float(model.vq.w_in.weight.grad.abs().sum()) > 0   # the projection learns through the straight-through path

    model = tiny_model().train()
    opted_stage = STAGES[3](StageConfig(trainable=STAGE_TRAINABLE[3]), LossConfig(stage3_vq=True, stage3_replay=0.5))
    opted_stage.configure(model)
    assert model.vq.codebook.requires_grad
    opted = stage_losses(model, 3, batch, weights=LossConfig(stage3_vq=True, stage3_replay=0.5))
    assert float(opted["loss"]) == pytest.approx(
        float(opted["next"]) + float(opted["vq"]) + 0.5 * float(opted["replay"]), rel=1e-5)
    opted["loss"].backward()
    assert model.vq.codebook.grad is not None and float(model.vq.codebook.grad.abs().sum()) > 0
    with pytest.raises(ValueError, match="stage3"):
        LossConfig(stage3_replay=-1.0).validate()
    with pytest.raises(ValueError, match="stage3_vq"):
        LossConfig(stage3_vq=1).validate()


def test_without_vision_stage2_trains_no_rgb_projection():
    for vision, used in ((True, True), (False, False)):
        model = tiny_model(vision=vision).train()
        make_stage(2).configure(model)
        assert all(p.requires_grad == used for p in model.rgb_proj.parameters())
        stage_losses(model, 2, frame_batch(2), torch.zeros(2, 1, 224, 224))["loss"].backward()
        assert any(p.grad is not None for p in model.rgb_proj.parameters()) == used


def grid_rgb_model(**kw):
    """A tiny model whose frozen RGB encoder is a (seeded, untrained) TactileGridRGB, which has
    the per-hand contact readout `rgb_prior` needs."""
    from handtouch.rgb_encoder import RGBEncoder, RGBEncoderInfo, TactileGridRGB
    torch.manual_seed(0)
    backbone = TactileGridRGB(size=28, width=16, channels=4, grid=7, hidden=16)
    torch.manual_seed(1)
    return HandTouch(tiny_cfg(**kw), RGBEncoder(backbone, RGBEncoderInfo("test-grid", "state_dict", "")))


def test_rgb_prior_fills_hidden_pixels_with_the_rgb_encoders_coarse_map():
    model, plain = grid_rgb_model(rgb_prior=True), grid_rgb_model()
    b = frame_batch(2)
    b["coverage"][:, :, :, :50] = 0                   # part of the canvas has no sensor
    cov = b["coverage"]
    fill = model.rgb_fill(b["rgb"], b["hand"], cov)
    bb = model.rgb_encoder.backbone
    with torch.no_grad():
        coarse = bb.predict(bb(b["rgb"].float() / 255), b["hand"])          # (B,1,7,7), per hand
    expected = coarse.repeat_interleave(32, 2).repeat_interleave(32, 3) * cov
    assert fill.shape == (2, 1, 224, 224) and torch.allclose(fill, expected)
    assert plain.rgb_fill(b["rgb"], b["hand"], cov) is None                # off: the paper's zeros
    mask = torch.zeros(2, 1, 224, 224)
    mask[:, :, :112] = 1
    target = b["tactile"] * cov
    shown = target * (1 - mask) + expected * mask
    two = grid_rgb_model(rgb_prior=True, mask_channel=True)
    with torch.no_grad():
        # the encoder sees the prior where pixels are hidden (the paper's 1 channel: only that) ...
        assert torch.allclose(model.encode(target, mask, fill), model.encoder(shown))
        # ... and, with the mask channel, which pixels those are
        assert torch.allclose(two.encode(target, mask, fill), two.encoder(torch.cat([shown, mask], 1)))
        assert not torch.equal(model.encode(target, mask, fill), model.encode(target, mask))
        # RGB-to-tactile now depends on the frame through the prior too, and visible pixels are kept
        other = torch.roll(b["rgb"], 1, 0)
        assert not torch.equal(model.rgb_to_tactile(b["rgb"], cov, b["hand"]),
                               model.rgb_to_tactile(other, cov, b["hand"]))


def test_rgb_prior_needs_an_encoder_with_a_readout():
    b = frame_batch(2)
    with pytest.raises(ValueError, match="readout"):    # random SmallConvRGB: no `predict`
        tiny_model(rgb_prior=True)
    assert tiny_model(rgb_prior=True, vision=False).rgb_fill(b["rgb"], b["hand"], b["coverage"]) is None
    with pytest.raises(ValueError, match="rgb_prior"):
        tiny_cfg(rgb_prior=1).validate()


def test_stage2_trains_on_the_rgb_prior():
    model = grid_rgb_model(rgb_prior=True)
    b = frame_batch(2)
    mask = torch.ones(2, 1, 224, 224)                    # complete: the RGB-to-tactile case
    with torch.no_grad():
        loss = stage_losses(model, 2, b, mask)["masked"]
        pred = model.rgb_to_tactile(b["rgb"], b["coverage"], b["hand"])
    # with everything hidden, stage 2's masked term is exactly the RGB-to-tactile error
    assert torch.allclose(loss, masked_mse(pred, b["tactile"] * b["coverage"], b["coverage"]), atol=1e-6)


def test_rgb_skip_adds_the_rgb_token_of_each_cell_before_the_fusion():
    b = frame_batch(2)
    model = grid_rgb_model(rgb_skip=True, patch=32)      # 7x7 tactile tokens, 7x7 RGB grid
    tokens = torch.randn(2, 49, 32)
    with torch.no_grad():
        vis = model.visual_tokens(b["rgb"])
        expected = model.fusion(model._with_hand(tokens + vis, b["hand"]), vis)[:, 1:]
        assert torch.allclose(model.fuse(tokens, b["rgb"], b["hand"]), expected)
    with pytest.raises(ValueError, match="one RGB token per tactile token"):
        tiny_model(rgb_skip=True, patch=16).fuse(torch.randn(2, 196, 32), b["rgb"], b["hand"])  # 196 vs 49


def test_one_backbone_pass_serves_the_rgb_prior_and_the_visual_tokens():
    """rgb_to_tactile (and stage 2) run the frozen backbone once per frame batch and hand its output to both
    the prior and the tokens: the same numbers as a pass each, one pass fewer."""
    model = grid_rgb_model(rgb_prior=True).eval()
    b = frame_batch(3)
    cov, hand, rgb = b["coverage"], b["hand"], b["rgb"]
    calls = []
    bb = model.rgb_encoder.backbone
    hook = bb.register_forward_hook(lambda *a: calls.append(1))
    with torch.no_grad():
        shared = model.rgb_to_tactile(rgb, cov, hand)
        assert len(calls) == 1
        blank = torch.zeros_like(cov)
        tokens = model.encode(blank, torch.ones_like(blank), model.rgb_fill(rgb, hand, cov))
        twice = model.quantise_decode(model.fuse(tokens, rgb, hand), cov)[0]
        assert len(calls) == 3 and torch.equal(shared, twice)
    hook.remove()


def test_rgb_to_tactile_from_features_computed_once_is_the_same():
    """The held-out gate and the misalignment control pass each frame's backbone output once
    (rgb_encoder.model_rgb_features) instead of the frame per pairing: the same prediction."""
    b, other = frame_batch(seed=0), frame_batch(seed=1)
    model = tiny_model().eval()
    rgb = torch.cat([b["rgb"], other["rgb"]])
    with torch.no_grad():
        features = model_rgb_features(model, rgb, batch_size=3)          # batches across the two
        for rows in (torch.tensor([0, 1]), torch.tensor([3, 0])):
            want = model.rgb_to_tactile(rgb[rows], b["coverage"], b["hand"])
            assert torch.allclose(model.rgb_to_tactile(rgb[rows], b["coverage"], b["hand"], features=features[rows]),
                                  want, atol=1e-6)
    assert model_rgb_features(object(), rgb, 3) is None                   # a model without a backbone: frames as fed
