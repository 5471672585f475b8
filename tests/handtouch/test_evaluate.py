import json
import math

import cv2
import numpy as np
import pytest
import torch

from handtouch.bench.evaluate import evaluate
from handtouch.bench.examples import collect_examples
from handtouch.bench.items import EvalConfig, EvalPart, part_masks, prepare, subsample
from handtouch.bench.references import CopyLastModel, ZerosModel
from handtouch.bench.report import markdown_table, render_predictions, write_results

S = 32          # small canvas: the bench code is size-agnostic, the tests stay fast


class ListDataset:
    def __init__(self, items):
        self.items = items

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]


def _regions():
    """Six vertical stripes = part ids 1..6, inside a covered square; row 0 outside the hand."""
    reg = np.repeat(np.repeat(np.arange(1, 7, dtype=np.uint8), S // 6 + 1)[:S][None], S, 0)
    reg[0] = 0
    return torch.from_numpy(reg)


def _coverage():
    cov = torch.zeros(1, S, S)
    cov[:, 1:, : S - 4] = 1.0      # part 6 (last stripe) only partly covered; row 0 uncovered
    return cov


def _frame_item(ep, f, static):
    yy, xx = np.mgrid[:S, :S]
    cx = 8 + (0 if static else f) + 4 * ep
    m = np.exp(-((yy - 16) ** 2 + (xx - cx) ** 2) / 20.0).astype(np.float32)
    if f % 5 == 4:
        m[:] = 0.0                 # some frames have no contact at all
    return {"tactile": torch.from_numpy(m)[None], "coverage": _coverage(), "regions": _regions(),
            "rgb": torch.full((3, S, S), 10 * f, dtype=torch.uint8), "hand": ep % 2,
            "task": 0, "scene": 0, "episode": ep, "frame": f}


def _part(episodes=4, frames=12, static=False, per_frame_ids=False):
    items = {(e, f): _frame_item(e, f, static) for e in range(episodes) for f in range(frames)}
    flat = [items[k] for k in sorted(items)]
    windows = []
    for e in range(episodes):
        for f in range(2, frames):
            group = [items[(e, g)] for g in (f - 2, f - 1, f)]
            # like htdata.read.torchdata.TactileWindowDataset: per-frame tensors stacked,
            # coverage / regions / hand / ids given once
            w = dict(group[-1])
            for k in ("tactile", "rgb", "frame"):
                w[k] = torch.stack([torch.as_tensor(x[k]) for x in group])
            if per_frame_ids:   # the evaluator also accepts per-frame stacked coverage / hand
                w["coverage"] = torch.stack([x["coverage"] for x in group])
                w["hand"] = torch.tensor([x["hand"] for x in group])
            windows.append(w)
    return EvalPart(frames=ListDataset(flat), windows=ListDataset(windows))


class RecordingModel(CopyLastModel):
    """Copy model that records what it was shown, to check leakage of hidden pixels."""

    name = "recording"

    def __init__(self):
        self.hidden_max = 0.0

    def inpaint(self, tactile, coverage, mask, rgb, hand):
        self.hidden_max = max(self.hidden_max, float((tactile * mask).abs().max()))
        return super().inpaint(tactile, coverage, mask, rgb, hand)


class NaNModel(ZerosModel):
    name = "nan"

    def rgb_to_tactile(self, rgb, coverage, hand):
        return torch.full_like(coverage, float("nan"))


def test_zeros_reference_matches_hand_computation():
    part = _part()
    res = evaluate(ZerosModel(), {"test": part}, parts=("test",), max_items=1000, exclude_radius=2)["test"]
    gts = torch.stack([it["tactile"] for it in part.frames.items])
    cov = _coverage()
    per_frame = ((gts ** 2) * cov).flatten(1).sum(1) / cov.sum()
    assert res["items"] == len(gts)
    assert res["rgb2tactile"]["f_covered"]["rmse"] == pytest.approx(float(per_frame.sqrt().mean()), rel=1e-6)
    # zeros vs contact -> cIoU 0; zeros vs empty frames (every 5th) -> 1
    empty = float((gts.flatten(1).amax(1) == 0).double().mean())
    assert res["rgb2tactile"]["f_covered"]["ciou"] == pytest.approx(empty)
    assert res["reconstruction"]["f_covered"]["rmse"] == pytest.approx(res["rgb2tactile"]["f_covered"]["rmse"])
    # whole canvas: every pixel counts, including the blob's tails outside the coverage
    whole = ((gts ** 2).flatten(1).mean(1)).sqrt().mean()
    assert res["rgb2tactile"]["f_full"]["rmse"] == pytest.approx(float(whole), rel=1e-6)
    assert res["rgb2tactile"]["f_full"]["rmse"] != pytest.approx(res["rgb2tactile"]["f_covered"]["rmse"])
    assert res["rgb2tactile"]["f_full"]["frames"] == len(gts)
    hole, hole_full = res["inpaint"]["h_covered"], res["inpaint"]["h_full"]
    assert hole_full["frames"] == hole["frames"] and hole["rmse"] is not None and hole_full["rmse"] is not None
    # constant embeddings score exactly the per-query chance (SSIM ties among the empty frames
    # lift it above 1/20); never the old index tie-break's agreement
    r = res["retrieval"]
    assert r["queries"] == len(gts)
    assert r["hit_at_1"] == r["constant_hit_at_1"] == pytest.approx(r["shuffled_hit_at_1"], abs=1e-12)
    assert r["recall_at_5"] == r["constant_recall_at_5"] == pytest.approx(r["shuffled_recall_at_5"], abs=1e-12)
    assert r["chance_hit_at_1"] == 0.05 and r["hit_at_1"] > 0.05


def test_copy_reference_reconstructs_and_copies_static_frames():
    res = evaluate(CopyLastModel(), {"test": _part(static=True)}, parts=("test",), max_items=1000)["test"]
    assert res["reconstruction"]["f_covered"]["rmse"] == 0.0 and res["reconstruction"]["f_covered"]["ciou"] == 1.0
    # only frames 4, 9 (empty) and their successors differ from the previous frame
    assert res["prediction"]["f_covered"]["rmse"] > 0.0
    h = res["inpaint"]["h_covered"]
    assert h["frames"] == res["items"] and h["skipped"] == 0
    assert res["inpaint"]["f_covered"]["rmse"] < h["rmse"]          # holes hold all the error
    assert res["windows"] == 4 * 10


@pytest.mark.parametrize("per_frame_ids", [False, True])
def test_copy_last_exact_on_constant_episodes(per_frame_ids):
    part = _part(static=True, per_frame_ids=per_frame_ids)
    for w in part.windows.items:                                 # make every window constant in time
        w["tactile"][:] = w["tactile"][-1]
    res = evaluate(CopyLastModel(), {"ood": part}, parts=("ood",), max_items=1000)["ood"]
    assert res["prediction"]["f_covered"]["rmse"] == 0.0 and res["prediction"]["f_covered"]["ciou"] == 1.0


def test_hidden_pixels_never_reach_the_model():
    model = RecordingModel()
    evaluate(model, {"test": _part()}, parts=("test",), max_items=30)
    assert model.hidden_max == 0.0


def test_seeded_subsample_is_deterministic_and_bounded():
    a = evaluate(CopyLastModel(), {"test": _part()}, parts=("test",), max_items=20, seed=7)
    b = evaluate(CopyLastModel(), {"test": _part()}, parts=("test",), max_items=20, seed=7)
    for r in (a, b):
        for track in r["test"].values():
            if isinstance(track, dict):
                track.pop("seconds", None)
        r["test"].pop("seconds")
    assert a == b
    assert a["test"]["items"] == 20 and a["test"]["windows"] == 20
    assert subsample(5, 10, 0).tolist() == [0, 1, 2, 3, 4]
    assert len(set(subsample(100, 10, 1).tolist())) == 10


def test_part_masks_pick_covered_parts_only():
    regions = _regions()[None].repeat(200, 1, 1)
    cov = torch.zeros(200, 1, S, S)
    cov[:100, :, 1:, :6] = 1.0                                  # only part 1 covered in the first half
    masks = part_masks(regions, cov, np.random.default_rng(0))
    assert torch.equal(masks[:100, 0], (regions[:100] == 1).float())
    assert masks[100:].sum() == 0                               # nothing covered -> empty mask
    cov_all = torch.ones(200, 1, S, S)
    chosen = {int(regions[0][m[0] > 0].unique().item()) for m in part_masks(regions, cov_all, np.random.default_rng(1))}
    assert chosen == {1, 2, 3, 4, 5, 6}


def test_bad_model_output_and_missing_part_raise():
    with pytest.raises(ValueError, match="nan.rgb_to_tactile returned NaN"):
        evaluate(NaNModel(), {"test": _part()}, parts=("test",), max_items=8)
    with pytest.raises(KeyError, match="ood"):
        evaluate(ZerosModel(), {"test": _part()}, parts=("test", "ood"))


def test_single_frame_episodes_skip_prediction_and_retrieval_gracefully():
    part = _part(episodes=3, frames=1)
    part.windows = ListDataset([])
    res = evaluate(CopyLastModel(), part, max_items=10)["all"]
    assert res["retrieval"]["queries"] == 0 and res["retrieval"]["hit_at_1"] is None
    assert res["prediction"]["f_covered"]["rmse"] is None and res["windows"] == 0
    assert res["reconstruction"]["f_covered"]["rmse"] == 0.0


def test_report_table_json_and_png(tmp_path):
    part = _part()
    results = {m.name: evaluate(m, {"test": part, "ood": part}, max_items=24)
               for m in (ZerosModel(), CopyLastModel())}
    doc = write_results(tmp_path, results, {"seed": 0})
    assert json.loads((tmp_path / "results.json").read_text())["results"].keys() == results.keys()
    table = (tmp_path / "results.md").read_text()
    verdicts, *sections = table.split("\n## ")[1:]
    assert verdicts.splitlines()[0] == "Verdicts against the references"
    assert len([row for row in verdicts.splitlines() if row.startswith("|")]) == 2     # references get no verdict row
    sections = [table, *sections]
    assert [sec.splitlines()[0] for sec in sections[1:]] == [
        "Covered pixels (f_covered, h_covered)", "Whole canvas (f_full, h_full)", "Retrieval and its chance levels"]
    for sec in sections[1:]:
        assert len([row for row in sec.splitlines() if row.startswith("|")]) == 2 + 4   # header, rule, 2 models x 2 parts
    lines = [row for row in sections[1].splitlines() if row.startswith("|")]
    assert lines[0].startswith("| Model | Retrieval Hit@1 | Retrieval R@5 | Inpaint F-RMSE | F-cIoU | H-RMSE")
    assert "Retrieval" not in sections[2].splitlines()[2]        # whole-canvas table: map metrics only
    full = results["copy-last-ref"]["ood"]["inpaint"]["h_full"]["rmse"]
    assert f"{full:.3f}" in sections[2] and "Hit@1 constant" in sections[3] and "0.050" in sections[3]
    assert "| copy-last-ref (ood) |" in table and doc["meta"] == {"seed": 0}
    rmse = results["zeros-ref"]["test"]["inpaint"]["f_covered"]["rmse"]
    assert f"{rmse:.3f}" in markdown_table({"zeros-ref": {"test": results["zeros-ref"]["test"]}})

    ex = collect_examples(CopyLastModel(), part, count=3)
    assert ex["gt"].shape == (3, S, S) and ex["rgb"].shape == (3, S, S, 3) and ex["rgb"].dtype == np.uint8
    # the figure shows the frames with the most contact, never an empty (f % 5 == 4) frame
    contact = (ex["gt"] * ex["coverage"]).sum((1, 2))
    assert (contact > 0).all() and list(contact) == sorted(contact, reverse=True)
    prepared = prepare({"test": part}, parts=("test",), cfg=EvalConfig(max_items=500))["test"]
    all_contact = torch.cat([(b["target"].float() * b["coverage"]).flatten(1).sum(1) for b in prepared.windows])
    assert contact[0] == pytest.approx(float(all_contact.max()))
    again = collect_examples(CopyLastModel(), prepared, count=3)
    assert all(np.array_equal(again[k], ex[k]) for k in ("gt", "prediction", "rgb"))   # deterministic
    img = render_predictions(ex, tmp_path / "predictions.png", title="copy-last-ref")
    back = cv2.imread(str(tmp_path / "predictions.png"))
    assert back.shape == img.shape and back.shape[1] == 6 * S and back.shape[0] > 3 * S
    assert math.isfinite(float(img.mean()))


class ReconstructingModel(ZerosModel):
    """Has the optional stage-1 `reconstruct`; its inpaint would score badly."""

    name = "recon"

    def reconstruct(self, tactile, coverage):
        return tactile * coverage


def test_reconstruction_track_prefers_model_reconstruct():
    res = evaluate(ReconstructingModel(), _part(), max_items=16)["all"]
    assert res["reconstruction"]["f_covered"]["rmse"] == 0.0
    assert res["inpaint"]["f_covered"]["rmse"] > 0.0


def _strip_seconds(res):
    for part in res.values():
        part.pop("seconds", None)
    return res


def test_prepared_parts_are_reused_with_identical_scores():
    from handtouch.bench.items import EvalConfig, prepare

    data = {"test": _part(), "ood": _part(static=True)}
    prepared = prepare(data, cfg=EvalConfig(max_items=20, seed=3))
    direct = _strip_seconds(evaluate(CopyLastModel(), data, max_items=20, seed=3))
    again = _strip_seconds(evaluate(CopyLastModel(), prepared))
    assert direct == again
    # non-half-exact maps are kept in float32 (no silent rounding of the ground truth)
    assert prepared["test"].frames[0]["tactile"].dtype == torch.float32
    half_exact = _part()
    for it in half_exact.frames.items:
        it["tactile"] = it["tactile"].half().float()
    assert prepare({"test": half_exact}, parts=("test",))["test"].frames[0]["tactile"].dtype == torch.float16


def test_smoke_learning_checks_compare_against_references():
    from handtouch.smokechecks import learning_checks

    levels = {"chance_hit_at_1": 0.05, "constant_hit_at_1": 0.05, "shuffled_hit_at_1": 0.06}
    good = {"hit_at_1": 0.3, **levels}
    assert all(c["ok"] for c in learning_checks(0.02, 0.1, good, perplexity=10.0))
    tied = {"hit_at_1": 0.2, **levels, "constant_hit_at_1": 0.25}   # empty-map ties lift the constant level
    assert not learning_checks(0.02, 0.1, tied, perplexity=10.0)[1]["ok"]
    chance = {"hit_at_1": 0.05, **levels}
    failed = [c["check"] for c in learning_checks(0.08, 0.1, chance, perplexity=2.0) if not c["ok"]]
    assert len(failed) == 3                              # no better than zeros, chance retrieval, collapsed
    assert not learning_checks(0.0701, 0.1, good, 10.0)[0]["ok"]     # just above 0.7 x zeros
    unscored = {"hit_at_1": None, **levels}
    assert not any(c["ok"] for c in learning_checks(None, 0.1, unscored, perplexity=float("nan")))
    assert not learning_checks(0.0, None, good, 10.0)[0]["ok"]      # no reference -> failed, never passed


def test_smoke_checks_fail_for_an_untrained_model():
    """The assertions are real: an untrained HandTouch does worse than predicting zeros."""
    from handtouch.config import ModelConfig
    from handtouch.model import HandTouch
    from handtouch.rgb_encoder import load_rgb_encoder
    from handtouch.smokechecks import RECON_RATIO, codebook_perplexity, learning_checks, reconstruction_rmse

    torch.manual_seed(0)
    model = HandTouch(ModelConfig(patch=32, dim=32, depth=1, heads=2, mlp_ratio=2.0, code_dim=8, codebook_size=16,
                                  decoder_depth=1, decoder_channels=16, fusion_depth=1, temporal_depth=1,
                                  predictor_depth=1), load_rgb_encoder("random:0"))
    # sparse contact on a 224 canvas, like the sample data: zeros is a strong baseline
    part = _part(episodes=2, frames=8)
    for it in [*part.frames.items, *part.windows.items]:
        t = it["tactile"]
        it["tactile"] = torch.nn.functional.pad(t, (0, 224 - S, 0, 224 - S))
        it["coverage"] = torch.nn.functional.pad(it["coverage"], (0, 224 - S, 0, 224 - S), value=1.0)
        it["regions"] = torch.nn.functional.pad(it["regions"], (0, 224 - S, 0, 224 - S))
        it["rgb"] = torch.nn.functional.pad(it["rgb"], (0, 224 - S, 0, 224 - S))
    prep = prepare({"test": part}, parts=("test",), cfg=EvalConfig(max_items=8, exclude_radius=1))["test"]
    rmse, zeros = reconstruction_rmse(model, prep), reconstruction_rmse(ZerosModel(), prep)
    perplexity = codebook_perplexity(model, prep)      # untrained: codebook never fitted to the maps
    checks = learning_checks(rmse, zeros, {"hit_at_1": 0.05, "chance_hit_at_1": 0.05}, perplexity)
    assert zeros > 0 and rmse > RECON_RATIO * zeros
    assert not checks[0]["ok"] and not checks[1]["ok"]
    assert math.isfinite(perplexity) and 1.0 <= perplexity <= 16.0


def _verdict_tracks(rmse, hole, pred, hit, rgb=None):
    chance = {"chance_hit_at_1": 0.05, "constant_hit_at_1": 0.06, "shuffled_hit_at_1": 0.05}
    return {"retrieval": {"hit_at_1": hit, **chance}, "reconstruction": {"f_covered": {"rmse": rmse}},
            "inpaint": {"f_covered": {"rmse": rmse}, "h_covered": {"rmse": hole}},
            "rgb2tactile": {"f_covered": {"rmse": rmse if rgb is None else rgb}},
            "prediction": {"f_covered": {"rmse": pred}}}


def test_verdicts_compare_every_track_with_the_references(tmp_path):
    from handtouch.bench.report import results_markdown
    from handtouch.bench.verdicts import model_verdicts, verdict_table

    results = {"m": {"test": _verdict_tracks(0.05, 0.04, 0.02, 0.3, rgb=0.12)},
               "zeros-ref": {"test": _verdict_tracks(0.09, 0.057, 0.088, 0.05)},
               "copy-last-ref": {"test": _verdict_tracks(0.02, 0.057, 0.013, 0.4, rgb=0.09)}}
    got = {v["label"]: (v["ok"], v["against"]) for v in model_verdicts(results)["m"]["test"]}
    assert got == {"retrieval Hit@1": (True, "chance"), "reconstruction F-RMSE": (True, "zeros-ref"),
                   "inpaint F-RMSE": (False, "copy-last-ref"), "inpaint H-RMSE": (True, "zeros-ref"),
                   "rgb2tactile F-RMSE": (False, "zeros-ref"),
                   "prediction F-RMSE": (False, "copy-last-ref")}   # the better of the two references
    table = verdict_table(results)
    assert "not yet 0.120 >= 0.090 zeros-ref" in table and "ok 0.300 > 0.060 chance" in table
    assert "zeros-ref (test)" not in table                          # references get no verdict row
    results["m"]["test"]["rgb2tactile"] = {"f_covered": {"rmse": None}}
    assert model_verdicts(results)["m"]["test"][4]["ok"] is None    # unmeasured: neither ok nor not yet
    checks = [{"check": "a", "value": 0.1, "limit": 0.09, "ok": False, "required": False},
              {"check": "b", "value": 0.1, "limit": 0.09, "ok": False}]
    md = results_markdown(results, {"checks": checks})
    assert "| a | 0.1000 | 0.0900 | missed (reported, not required) |" in md and "| b | 0.1000 | 0.0900 | FAILED |" in md
    assert md.index("## Verdicts") < md.index("## Covered pixels")


def test_smoke_rgb_check_is_required_on_test():
    from handtouch.smokechecks import rgb_check

    results = {"m": {"test": {"rgb2tactile": {"f_covered": {"rmse": 0.12}}}},
               "zeros-ref": {"test": {"rgb2tactile": {"f_covered": {"rmse": 0.09}}}}}
    check = rgb_check(results, "m")
    assert check["ok"] is False and check["required"] is True and check["limit"] == 0.09
    assert rgb_check(results, "m", "test", required=False)["required"] is False
    results["m"]["test"]["rgb2tactile"]["f_covered"]["rmse"] = 0.09
    assert rgb_check(results, "m")["ok"] is False                    # a tie with all zeros is not better
    results["m"]["test"]["rgb2tactile"]["f_covered"]["rmse"] = 0.05
    assert rgb_check(results, "m")["ok"] is True


def test_results_open_with_a_headline_and_the_lag_curves_are_plotted(tmp_path):
    import cv2

    from handtouch.bench.report import colour_bar, headline_markdown, render_lag_curves, results_markdown

    curve = {"shifts": list(range(-3, 4)), "auroc": [0.5, 0.6, 0.8, 0.9, 0.8, None, 0.5], "best_shift": 0,
             "best_auroc": 0.9}
    gate = {"ood": {"where": "held-out (ood) cup", "required": True, "lag": curve,
                    "timing": {"auroc": 0.9, "mispaired_auroc": 0.5, "phase_matched_auroc": 0.55,
                               "position_auroc": 0.6}}}
    ok = {"check": "a", "value": 1, "limit": 0, "ok": True}
    missed = {"check": "b", "value": 0, "limit": 1, "ok": False, "required": False}
    head = headline_markdown({"checks": [ok, missed], "heldout_gate": gate})
    assert head.startswith("**PASSED**: 1 of 1 required checks ok; 1 more reported only.")
    assert "AUROC 0.9000 against 0.5000" in head and "0.5500 at the same moment" in head and "0.6000 for a clock" in head
    failed = headline_markdown({"checks": [{**ok, "ok": False}], "broken_control": "lagged"})
    assert failed.startswith("**FAILED (1 of 1 required checks)") and "expected outcome" in failed
    assert "- failed: a" in failed
    assert results_markdown({}, {"checks": [ok]}).index("**PASSED**") < results_markdown({}, {"checks": [ok]}).index(
        "## Verdicts")
    img = render_lag_curves(gate, tmp_path / "lag.png")
    assert cv2.imread(str(tmp_path / "lag.png")).shape == img.shape and (img < 128).any()
    with pytest.raises(ValueError, match="no lag curves"):
        render_lag_curves({"test": {"where": "test", "timing": {}}}, tmp_path / "none.png")
    bar = colour_bar(600)
    assert bar.shape[1] == 600 and len({tuple(p) for p in bar[10, 40:300]}) > 50    # a colour ramp
