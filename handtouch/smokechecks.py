"""The smoke's pass/fail checks of what HandTouch learned, and the run's exit status.

Each check is a dict {"check", "value", "limit", "ok", "required"}; handtouch.smoke collects them
(with the RGB controls of handtouch.rgb_pretrain and the held-out gate of handtouch.contact_gate),
results.md lists them, `verdict` turns them into the exit status.
"""

from __future__ import annotations

import math
import sys

import torch

from handtouch.bench.evaluate import reconstruct
from handtouch.bench.items import PreparedPart
from handtouch.bench.metrics import MapMetrics
from handtouch.bench.verdicts import ZEROS
from htdata.read import keys

RECON_RATIO = 0.7
# 64 codes in the smoke config; a collapsed codebook scores ~1. Healthy runs use 15-30.
PERPLEXITY_FLOOR = 4.0


def reconstruction_rmse(model, prep: PreparedPart) -> float | None:
    """Per-frame mean F-RMSE of stage-1 autoencoding over the prepared items (the
    reconstruction track's number); None if no frame has a covered pixel."""
    metrics = MapMetrics()
    if isinstance(model, torch.nn.Module):
        model.eval()
    with torch.inference_mode():
        for b in prep.frames:
            tactile, coverage = b[keys.TACTILE].float(), b[keys.COVERAGE].float()
            metrics.update(reconstruct(model, tactile, coverage, b[keys.RGB], b[keys.HAND]), tactile, coverage)
    return metrics.result()["rmse"]


def codebook_perplexity(model, prep: PreparedPart) -> float:
    """exp(entropy) of code usage over every token of the prepared maps (eval mode: no restarts)."""
    if not (hasattr(model, "vq") and hasattr(model, "encode")):
        raise TypeError(f"{model.name}: no vq/encode; codebook perplexity needs a HandTouch model")
    counts = torch.zeros(model.vq.codebook_size, dtype=torch.float64)
    model.eval()
    with torch.inference_mode():
        for b in prep.frames:
            _, idx, _, _ = model.vq(model.encode(b[keys.TACTILE].float() * b[keys.COVERAGE].float()))
            counts += torch.bincount(idx.flatten(), minlength=counts.numel()).double()
    if counts.sum() == 0:
        return float("nan")
    p = counts[counts > 0] / counts.sum()
    return float(torch.exp(-(p * p.log()).sum()))


def learning_checks(stage1_rmse: float | None, zeros_rmse: float | None, retrieval: dict,
                    perplexity: float) -> list[dict]:
    """The smoke run's pass/fail criteria, each with the numbers it compared.

    stage1_rmse / zeros_rmse: reconstruction F-RMSE of the stage-1 model and of the
    all-zeros predictor on the same held-out items; retrieval: the final model's
    retrieval track (test); perplexity: the final model's codebook perplexity.
    A missing (None / NaN) number fails its check.
    """
    def known(x) -> bool:
        return x is not None and math.isfinite(x)

    hit = retrieval.get("hit_at_1")
    # the highest chance level: 1/20, a constant embedding (ties of empty maps), shuffled embeddings
    levels = [retrieval.get(k) for k in ("chance_hit_at_1", "constant_hit_at_1", "shuffled_hit_at_1")]
    chance = max(levels) if all(known(x) for x in levels) else None
    return [
        {"check": f"stage-1 reconstruction F-RMSE <= {RECON_RATIO} x all-zeros (same held-out items)",
         "value": stage1_rmse, "limit": RECON_RATIO * zeros_rmse if known(zeros_rmse) else None,
         "ok": known(stage1_rmse) and known(zeros_rmse) and stage1_rmse <= RECON_RATIO * zeros_rmse},
        {"check": "retrieval Hit@1 above chance (max of 1/20, constant and shuffled embeddings)",
         "value": hit, "limit": chance,
         "ok": known(hit) and known(chance) and hit > chance},
        {"check": f"codebook perplexity >= {PERPLEXITY_FLOOR}", "value": perplexity,
         "limit": PERPLEXITY_FLOOR, "ok": known(perplexity) and perplexity >= PERPLEXITY_FLOOR},
    ]


def rgb_check(results: dict, model: str, part: str = "test", required: bool = True) -> dict:
    """RGB-to-tactile F-RMSE (covered) of `model` below all zeros' on the same items.

    Required on test (with the RGB prior, docs/HANDTOUCH.md "RGB prior"). On held-out tasks F-RMSE per
    frame mostly measures sparsity (handtouch/bench/timing.py): there the gate is contact timing and
    F-RMSE is reported per frame, pooled and on contact frames (handtouch.contact_gate)."""
    value = results[model][part]["rgb2tactile"]["f_covered"]["rmse"]
    limit = results[ZEROS][part]["rgb2tactile"]["f_covered"]["rmse"]
    ok = value is not None and limit is not None and math.isfinite(value) and value < limit
    return {"check": f"RGB-to-tactile F-RMSE ({part}) < all zeros", "value": value, "limit": limit, "ok": ok,
            "required": required}


# What must fail on each broken control corpus (handtouch.smokedata.BROKEN), by words of the check.
MUST_CATCH = {
    "mispaired": ("the held-out gate", lambda c: ("AUROC" in c or c.startswith("lag:")) and "held-out (ood)" in c),
    "reversed": ("the held-out gate", lambda c: ("AUROC" in c or c.startswith("lag:")) and "held-out (ood)" in c),
    "lagged": ("the lag check", lambda c: c.startswith("lag:") and "lags the glove" in c),
}
DESCRIBED = {"mispaired": "mis-paired RGB", "reversed": "video played backwards", "lagged": "video that lags the glove"}


def verdict(checks: list[dict], control: bool | str = False) -> int:
    """The smoke's exit status: 1 if a required check failed. control (a broken control corpus:
    "mispaired", "reversed", "lagged"; True means "mispaired"): 0 only if what must catch it failed
    (MUST_CATCH: the held-out gate on the held-out (ood) task; for the lag, the lag check naming it)."""
    failed = [c["check"] for c in checks if not c["ok"] and c.get("required", True)]
    if control:
        kind = "mispaired" if control is True else control
        what, catches = MUST_CATCH[kind]
        caught = [c for c in failed if catches(c)]
        if caught:
            print(f"smoke: control: {what} failed on {DESCRIBED[kind]}, as it must: {caught}", flush=True)
            return 0
        print(f"smoke: control: {what} PASSED on {DESCRIBED[kind]}: it does not catch this broken "
              "pipeline", file=sys.stderr)
        return 1
    if failed:
        print(f"smoke: HandTouch did not learn: failed {failed}", file=sys.stderr)
        return 1
    return 0
