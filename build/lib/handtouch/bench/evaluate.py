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

Items: at most `max_items` frames (and windows) per part, drawn without
replacement by a seeded RNG, sorted, so every model sees the same items.

Data: a dataset root (str/Path: parts are loaded with htdata.torchdata), or
in-memory `EvalPart`s (a Mapping part -> EvalPart, or one EvalPart scored as
part "all"). An `EvalPart` holds Dataset-like objects (len + getitem -> dict
of tensors, DESIGN.md "Reader / torch").

Several models: `prepare(...)` decodes each part once and fixes the
model-independent parts (items, inpainting masks, the retrieval SSIM
reference); pass its result to `evaluate` for every model.

Reference predictors (`ZerosModel`, `CopyLastModel`) implement the same
interface so learning can be judged against them.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from handtouch.api import TactileModel
from handtouch.bench.metrics import TrackMetrics
from handtouch.bench.retrieval import RetrievalConfig, RetrievalReference, retrieval_reference, score_retrieval
from handtouch.config import WINDOW
from htdata import keys

NUM_PARTS = 6          # part ids 1..6 (thumb, index, middle, ring, little, palm)
TRACKS = ("retrieval", "reconstruction", "inpaint", "rgb2tactile", "prediction")


@dataclass
class EvalConfig:
    max_items: int = 200
    seed: int = 0
    batch_size: int = 16
    num_candidates: int = 20
    exclude_radius: int = 5

    def validate(self) -> "EvalConfig":
        if self.max_items < 1 or self.batch_size < 1:
            raise ValueError(f"max_items and batch_size must be >= 1, got {self.max_items}, {self.batch_size}")
        RetrievalConfig(num_candidates=self.num_candidates, exclude_radius=self.exclude_radius).validate()
        return self


@dataclass
class EvalPart:
    """Dataset-like sources of one split part; `windows` may be None (prediction is then skipped)."""

    frames: Any
    windows: Any = None


def load_part(dataset_root: str | Path, split_name: str | None, part: str) -> EvalPart:
    """Open a committed dataset's part through htdata.torchdata (split None = whole dataset)."""
    from htdata.torchdata import TactileFrameDataset, TactileWindowDataset

    root = str(dataset_root)
    return EvalPart(frames=TactileFrameDataset(root, split=split_name, part=part),
                    windows=TactileWindowDataset(root, window=WINDOW, split=split_name, part=part))


def subsample(n: int, max_items: int, seed: int) -> np.ndarray:
    """Sorted indices of at most max_items of n items, seeded."""
    if n <= max_items:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, max_items, replace=False))


def _collate(items: list[dict]) -> dict[str, torch.Tensor]:
    out = {}
    for key in items[0]:
        vals = [it[key] for it in items]
        if isinstance(vals[0], torch.Tensor):
            out[key] = torch.stack(vals)
        elif isinstance(vals[0], np.ndarray):
            out[key] = torch.from_numpy(np.stack(vals))
        elif isinstance(vals[0], (int, float, bool, np.integer, np.floating)):
            out[key] = torch.as_tensor(vals)
    return out


def iterate_batches(dataset, indices: np.ndarray, batch_size: int):
    for start in range(0, len(indices), batch_size):
        yield _collate([dataset[int(i)] for i in indices[start:start + batch_size]])


def _hand(batch: dict) -> torch.Tensor:
    """(B,) long; window items may carry a per-frame hand (B,W): the last frame's is used."""
    h = batch[keys.HAND]
    return (h[:, -1] if h.ndim == 2 else h.reshape(-1)).long()


def _checked(pred: torch.Tensor, like: torch.Tensor, what: str) -> torch.Tensor:
    pred = torch.as_tensor(pred).float()
    if pred.shape != like.shape:
        raise ValueError(f"{what} returned shape {tuple(pred.shape)}, expected {tuple(like.shape)}")
    if not torch.isfinite(pred).all():
        raise ValueError(f"{what} returned NaN/Inf")
    return pred


def part_masks(regions: torch.Tensor, coverage: torch.Tensor, generator: np.random.Generator) -> torch.Tensor:
    """One covered anatomical part per frame -> mask (B,1,H,W) float, 1 = hidden.

    The part is drawn uniformly among the parts with at least one covered
    pixel in that frame; a frame with no covered part gets an empty mask
    (its H- metrics are then skipped, not faked).
    """
    covered = coverage[:, 0] > 0.5
    present = torch.stack([((regions == p) & covered).flatten(1).any(1) for p in range(1, NUM_PARTS + 1)], 1)
    draw = torch.from_numpy(generator.random(present.shape))
    choice = torch.where(present, draw, torch.full_like(draw, -1.0)).argmax(1) + 1   # part id 1..6
    choice = torch.where(present.any(1), choice, torch.zeros_like(choice))
    return (regions == choice[:, None, None].to(regions.dtype)).logical_and(choice[:, None, None] > 0)[:, None].float()


def reconstruct(model: TactileModel, tactile, coverage, rgb, hand) -> torch.Tensor:
    """Stage-1 autoencoding: `model.reconstruct(tactile, coverage)` when the model has it
    (HandTouch does), else `inpaint` with nothing hidden."""
    if callable(getattr(model, "reconstruct", None)):
        return model.reconstruct(tactile, coverage)
    return model.inpaint(tactile, coverage, torch.zeros_like(tactile), rgb, hand)


def _compact(x: torch.Tensor) -> torch.Tensor:
    """float16 if that is lossless (decoded EXR half maps are), else unchanged: halves cache memory."""
    if x.dtype == torch.float32:
        h = x.half()
        if torch.equal(h.float(), x):
            return h
    return x


@dataclass
class PreparedPart:
    """A part's evaluation items decoded once, in batches, with everything model-independent
    (inpainting masks, the retrieval SSIM reference) fixed, so every model sees the same."""

    frames: list[dict]          # tactile, coverage (u8), rgb, hand, episode, frame, mask (u8, 1 = hidden)
    windows: list[dict]         # rgb_window, tactile_window, coverage, hand, target, mask (u8, frame T)
    reference: RetrievalReference
    items: int
    num_windows: int


def prepare_part(part: EvalPart, cfg: EvalConfig) -> PreparedPart:
    cfg.validate()
    n = len(part.frames)
    if n == 0:
        raise ValueError("evaluation part has no frames")
    idx = subsample(n, cfg.max_items, cfg.seed)
    rng = np.random.default_rng(cfg.seed + 1)
    frames, maps, episodes, frame_ids = [], [], [], []
    for b in iterate_batches(part.frames, idx, cfg.batch_size):
        tactile, coverage = b[keys.TACTILE].float(), b[keys.COVERAGE].float()
        frames.append({keys.TACTILE: _compact(tactile), keys.COVERAGE: (coverage > 0.5).to(torch.uint8),
                       keys.RGB: b[keys.RGB], keys.HAND: _hand(b),
                       keys.EPISODE: b[keys.EPISODE].reshape(-1), keys.FRAME: b[keys.FRAME].reshape(-1),
                       "mask": part_masks(b[keys.REGIONS], coverage, rng).to(torch.uint8)})
        maps.append(tactile[:, 0])
        episodes.append(b[keys.EPISODE].reshape(-1))
        frame_ids.append(b[keys.FRAME].reshape(-1))
    reference = retrieval_reference(
        torch.cat(maps), torch.cat(episodes).numpy(), torch.cat(frame_ids).numpy(),
        RetrievalConfig(num_candidates=cfg.num_candidates, exclude_radius=cfg.exclude_radius, seed=cfg.seed))
    windows = []
    widx = np.zeros(0, np.int64)
    if part.windows is not None and len(part.windows) > 0:
        widx = subsample(len(part.windows), cfg.max_items, cfg.seed)
        wrng = np.random.default_rng(cfg.seed + 2)
        for b in iterate_batches(part.windows, widx, cfg.batch_size):
            rgb_w, tac_w, cov_t, hand, target = window_inputs(b)
            regions = b[keys.REGIONS][:, -1] if b[keys.REGIONS].ndim == 4 else b[keys.REGIONS]
            windows.append({"rgb_window": rgb_w, "tactile_window": _compact(tac_w),
                            "coverage": (cov_t > 0.5).to(torch.uint8), "hand": hand, "target": _compact(target),
                            # frame T's inpainting mask, for the predictions figure
                            "mask": part_masks(regions, cov_t, wrng).to(torch.uint8)})
    return PreparedPart(frames, windows, reference, int(len(idx)), int(len(widx)))


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


def window_inputs(b: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Window batch -> (rgb_window (B,W,3,H,W), tactile_window (B,W-1,1,H,W), coverage_T, hand, target_T)."""
    tactile = b[keys.TACTILE].float()
    coverage = b[keys.COVERAGE].float()
    cov_t = coverage[:, -1] if coverage.ndim == 5 else coverage
    return b[keys.RGB], tactile[:, :-1], cov_t, _hand(b), tactile[:, -1]


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


def resolve_parts(dataset_root, split_name: str | None, parts: Sequence[str]) -> dict[str, EvalPart | PreparedPart]:
    if isinstance(dataset_root, (EvalPart, PreparedPart)):
        return {"all": dataset_root}
    if isinstance(dataset_root, Mapping):
        missing = [p for p in parts if p not in dataset_root]
        if missing:
            raise KeyError(f"evaluation data has no part(s) {missing}; available: {sorted(dataset_root)}")
        return {p: dataset_root[p] if isinstance(dataset_root[p], (EvalPart, PreparedPart))
                else EvalPart(dataset_root[p]) for p in parts}
    return {p: load_part(dataset_root, split_name, p) for p in parts}


def prepare(dataset_root, split_name: str | None = None, parts: Sequence[str] = ("test", "ood"),
            cfg: EvalConfig | None = None) -> dict[str, PreparedPart]:
    """Decode and fix each part's items once (reuse the result for several models)."""
    cfg = (cfg or EvalConfig()).validate()
    return {name: src if isinstance(src, PreparedPart) else prepare_part(src, cfg)
            for name, src in resolve_parts(dataset_root, split_name, parts).items()}


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


def contact_order(windows: list[dict]) -> np.ndarray:
    """Prepared window positions ordered by ground-truth contact at T (sum over covered
    pixels), largest first; ties keep the lower position (stable, deterministic)."""
    totals = [(b["target"].float() * b["coverage"].float()).flatten(1).sum(1) for b in windows]
    if not totals:
        return np.zeros(0, np.int64)
    return np.argsort(-torch.cat(totals).double().numpy(), kind="stable")


def collect_examples(model: TactileModel, part: EvalPart | PreparedPart, count: int = 4,
                     cfg: EvalConfig | None = None) -> dict[str, np.ndarray]:
    """The `count` evaluation windows with the most contact at frame T, with every track's
    output, for report.render_predictions (frames without contact show nothing).

    `part` is a PreparedPart (its items) or an EvalPart (prepared first with `cfg`).
    Returns float32 arrays (N,224,224) for gt, inpaint, rgb2tactile, prediction,
    mask, coverage and uint8 rgb (N,224,224,3).
    """
    prep = part if isinstance(part, PreparedPart) else prepare_part(part, (cfg or EvalConfig()).validate())
    if not prep.windows:
        raise ValueError("collect_examples needs window items (the part has no windows)")
    sizes = [len(b["target"]) for b in prep.windows]
    starts = np.cumsum([0, *sizes])
    picks = contact_order(prep.windows)[:count]
    batch_of = np.searchsorted(starts, picks, side="right") - 1

    def gather(key: str) -> torch.Tensor:
        return torch.stack([prep.windows[k][key][i - starts[k]] for k, i in zip(batch_of, picks)])

    rgb_w, tac_w, hand = gather("rgb_window"), gather("tactile_window").float(), gather("hand")
    cov_t, target, mask = gather("coverage").float(), gather("target").float(), gather("mask").float()
    rgb_t = rgb_w[:, -1]
    if isinstance(model, torch.nn.Module):
        model.eval()
    with torch.inference_mode():
        inp = model.inpaint(target * (1 - mask), cov_t, mask, rgb_t, hand)
        r2t = model.rgb_to_tactile(rgb_t, cov_t, hand)
        nxt = model.predict_next(rgb_w, tac_w, cov_t, hand)
    rgb_np = rgb_t.float()
    if rgb_t.dtype != torch.uint8:
        rgb_np = rgb_np * 255.0
    return {
        "rgb": rgb_np.clamp(0, 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy(),
        "gt": target[:, 0].numpy(),
        "inpaint": inp.float()[:, 0].numpy(),
        "rgb2tactile": r2t.float()[:, 0].numpy(),
        "prediction": nxt.float()[:, 0].numpy(),
        "mask": mask[:, 0].numpy(),
        "coverage": cov_t[:, 0].numpy(),
    }


# ---- reference predictors --------------------------------------------------

class ZerosModel:
    """Predicts no contact everywhere; embeds every map to the same vector
    (retrieval then follows the tie rule: a chance-level reference)."""

    name = "zeros-ref"

    def embed(self, tactile, coverage, hand):
        return torch.ones(tactile.shape[0], 1)

    def inpaint(self, tactile, coverage, mask, rgb, hand):
        return torch.zeros_like(tactile, dtype=torch.float32)

    def rgb_to_tactile(self, rgb, coverage, hand):
        return torch.zeros_like(coverage, dtype=torch.float32)

    def predict_next(self, rgb_window, tactile_window, coverage, hand):
        return torch.zeros_like(coverage, dtype=torch.float32)


class CopyLastModel(ZerosModel):
    """Copies what it is given: the visible map for inpainting (holes stay 0),
    the last tactile frame for prediction; embeds the 8x8-pooled raw map
    (a pixel-space retrieval reference). RGB-to-tactile stays all zeros."""

    name = "copy-last-ref"

    def embed(self, tactile, coverage, hand):
        return torch.nn.functional.avg_pool2d(tactile.float(), 8).flatten(1)

    def inpaint(self, tactile, coverage, mask, rgb, hand):
        return tactile.float() * (1 - mask)

    def predict_next(self, rgb_window, tactile_window, coverage, hand):
        return tactile_window[:, -1].float()
