"""HT-Bench: score any `TactileModel` on the four tracks.

Tracks (per split part, e.g. test and ood):
- retrieval: 1-vs-20 Hit@1 / Recall@5 of `embed` against the SSIM ranking
  (see retrieval.py for the candidate rule);
- reconstruction: stage-1 autoencoding, `model.reconstruct(tactile, coverage)`
  if the model has it (not part of TactileModel), else `inpaint` with an
  empty mask; F- metrics (the check the smoke run asserts on);
- inpaint: one anatomical part (thumb..palm) per frame is hidden, drawn by a
  seeded RNG among the parts the glove covers in that frame. Hidden pixels
  are zeroed before the model sees the map (a model cannot leak them). F-
  and H- (hidden part) metrics;
- rgb2tactile: `rgb_to_tactile`, F- metrics;
- prediction: `predict_next` on windows of WINDOW (3) frames, F- metrics on frame T.
Every F-/H- metric is reported over covered pixels and over the whole
canvas / hidden part, labelled (`f_covered`, `f_full`, `h_covered`, `h_full`;
metrics.py). Retrieval carries its chance levels (retrieval.py).

The items every model sees (subsampled frames and windows, inpainting
masks, the retrieval reference) are prepared once: handtouch.bench.items.
Reference predictors (`ZerosModel`, `CopyLastModel`, handtouch.bench.references)
implement the same interface so learning can be judged against them; the
predictions figure's windows come from handtouch.bench.examples.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import torch

from handtouch.api import TactileModel
from handtouch.bench.items import EvalConfig, PreparedPart, prepare
from handtouch.bench.metrics import TrackMetrics
from handtouch.bench.retrieval import score_retrieval
from htdata.read import keys


def _checked(pred: torch.Tensor, like: torch.Tensor, what: str) -> torch.Tensor:
    pred = torch.as_tensor(pred).float()
    if pred.shape != like.shape:
        raise ValueError(f"{what} returned shape {tuple(pred.shape)}, expected {tuple(like.shape)}")
    if not torch.isfinite(pred).all():
        raise ValueError(f"{what} returned NaN/Inf")
    return pred


def reconstruct(model: TactileModel, tactile, coverage, rgb, hand) -> torch.Tensor:
    """Stage-1 autoencoding: `model.reconstruct(tactile, coverage)` when the model has it
    (HandTouch does), else `inpaint` with nothing hidden."""
    if callable(getattr(model, "reconstruct", None)):
        return model.reconstruct(tactile, coverage)
    return model.inpaint(tactile, coverage, torch.zeros_like(tactile), rgb, hand)


def _frame_tracks(model: TactileModel, prep: PreparedPart) -> dict:
    recon, inpaint, r2t = TrackMetrics(), TrackMetrics(holes=True), TrackMetrics()
    embs = []
    times = {"embed": 0.0, "reconstruct": 0.0, "inpaint": 0.0, "rgb2tactile": 0.0}

    def timed(key, fn, *a):
        t0 = time.perf_counter()
        out = fn(*a)
        times[key] += time.perf_counter() - t0
        return out

    for b in prep.frames:
        tactile, coverage, rgb, hand = b[keys.TACTILE].float(), b[keys.COVERAGE].float(), b[keys.RGB], b[keys.HAND]
        mask = b["mask"].float()
        e = torch.as_tensor(timed("embed", model.embed, tactile, coverage, hand)).float()
        if e.ndim != 2 or e.shape[0] != tactile.shape[0]:
            raise ValueError(f"{model.name}.embed returned shape {tuple(e.shape)}, expected (B,E)")
        embs.append(e)
        rec = timed("reconstruct", reconstruct, model, tactile, coverage, rgb, hand)
        recon.update(_checked(rec, tactile, f"{model.name}.reconstruct"), tactile, coverage)
        filled = timed("inpaint", model.inpaint, tactile * (1 - mask), coverage, mask, rgb, hand)
        filled = _checked(filled, tactile, f"{model.name}.inpaint")
        inpaint.update(filled, tactile, coverage, mask)
        guess = timed("rgb2tactile", model.rgb_to_tactile, rgb, coverage, hand)
        r2t.update(_checked(guess, tactile, f"{model.name}.rgb_to_tactile"), tactile, coverage)
    return {
        "retrieval": score_retrieval(prep.reference, torch.cat(embs)),
        "reconstruction": recon.result(),
        "inpaint": inpaint.result(),
        "rgb2tactile": r2t.result(),
        "seconds": times,
    }


def _prediction_track(model: TactileModel, prep: PreparedPart) -> tuple[dict, float]:
    pred_metrics = TrackMetrics()
    seconds = 0.0
    for b in prep.windows:
        target, cov_t = b["target"].float(), b["coverage"].float()
        t0 = time.perf_counter()
        pred = model.predict_next(b["rgb_window"], b["tactile_window"].float(), cov_t, b["hand"])
        seconds += time.perf_counter() - t0
        pred_metrics.update(_checked(pred, target, f"{model.name}.predict_next"), target, cov_t)
    return pred_metrics.result(), seconds


def score_part(model: TactileModel, prep: PreparedPart) -> dict:
    """All tracks of one model on one prepared part."""
    out = _frame_tracks(model, prep)
    out["prediction"], out["seconds"]["prediction"] = _prediction_track(model, prep)
    out["items"] = prep.items
    out["windows"] = prep.num_windows
    return out


def evaluate(model: TactileModel, dataset_root, split_name: str | None = None,
             parts: Sequence[str] = ("test", "ood"), max_items: int = 200, seed: int = 0,
             *, batch_size: int = 16, exclude_radius: int = 5) -> dict[str, dict]:
    """Score `model` on every track of every part -> {part: {track: metrics}}.

    `dataset_root` may also be in-memory data (see module doc) or the result
    of `prepare` (then max_items/seed/batch_size/exclude_radius are those of
    the preparation).
    """
    cfg = EvalConfig(max_items=max_items, seed=seed, batch_size=batch_size,
                     exclude_radius=exclude_radius).validate()
    prepared = prepare(dataset_root, split_name, parts, cfg)
    if isinstance(model, torch.nn.Module):
        model.eval()
    with torch.inference_mode():
        return {name: score_part(model, prep) for name, prep in prepared.items()}
