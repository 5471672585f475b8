"""Map metrics of HT-Bench: RMSE and contact IoU over a pixel region.

Every map track is scored over two regions, both reported and labelled
(`REGIONS`):

    f_covered  the glove's sensor-covered pixels            (F- metrics)
    f_full     every pixel of the 224x224 canvas            (F-, the paper's "full tactile map")
    h_covered  covered pixels of the hidden part            (H- metrics, inpainting only)
    h_full     every pixel of the hidden part               (H-, paper convention)

The covered figures are the honest ones for partial-coverage gloves: the
target is 0 wherever there is no sensor, so whole-canvas figures reward a
model for the empty canvas (an all-zeros predictor looks better the smaller
the glove). The full figures are there to be set beside the paper's.

    rmse  = sqrt( sum_region (P_hat - P)^2 / |region| )          raw predictions
    cIoU  = sum_region min(P, P_hat) / sum_region max(P, P_hat)    P_hat clamped to [0,1]

cIoU clamps the prediction to the target's range [0,1] (a deviation from the
literal formula): with a raw regression output, a negative prediction makes
the intersection negative (cIoU < 0) and a prediction above 1 inflates the
union without bound, so the ratio would no longer be an overlap fraction of
contact mass. Out-of-range values are still penalised, by the RMSE, which
uses the raw prediction.

Defined edge cases:
- both maps zero over a non-empty region -> cIoU = 1 (a correct "no
  contact" prediction); a zero denominator never yields NaN;
- a frame whose region is empty (no covered pixel, or no hidden part) is
  skipped and counted in `skipped`; it contributes to no mean, and a region
  no frame has gives None (JSON null) values, never NaN;
- NaN/Inf in a prediction or target -> ValueError (a broken model must
  not score).

Two aggregations are reported per region: the mean of per-frame values
(`rmse`, `ciou`) and the pooled value over all counted pixels of all frames
(`rmse_pooled` = sqrt(total squared error / total pixels), `ciou_pooled`
= total min / total max), which weights frames by their contact.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


def _frames(x, name: str) -> torch.Tensor:
    """(B,1,H,W) / (B,H,W) -> (B,H*W) float32 (per-pixel work; sums are taken in float64)."""
    t = torch.as_tensor(x)
    if t.ndim == 4:
        if t.shape[1] != 1:
            raise ValueError(f"{name}: expected 1 channel, got shape {tuple(t.shape)}")
        t = t[:, 0]
    if t.ndim != 3:
        raise ValueError(f"{name}: expected (B,1,H,W) or (B,H,W), got shape {tuple(t.shape)}")
    return t.reshape(t.shape[0], -1).to(torch.float32)


@dataclass
class FrameScores:
    """Per-frame sums over the region; the accumulator adds these up."""

    sq_err: torch.Tensor     # (B,) sum of squared error
    count: torch.Tensor      # (B,) number of region pixels
    inter: torch.Tensor      # (B,) sum of min(P, P_hat)
    union: torch.Tensor      # (B,) sum of max(P, P_hat)

    @property
    def valid(self) -> torch.Tensor:
        return self.count > 0

    def rows(self, index) -> "FrameScores":
        """The scores of the frames `index` selects (an index array or mask over the batch)."""
        return FrameScores(self.sq_err[index], self.count[index], self.inter[index], self.union[index])

    @property
    def rmse(self) -> torch.Tensor:
        """(B,) per-frame RMSE; NaN marks frames with an empty region (never averaged)."""
        return torch.where(self.valid, (self.sq_err / self.count.clamp(min=1)).sqrt(),
                           torch.full_like(self.sq_err, float("nan")))

    @property
    def ciou(self) -> torch.Tensor:
        """(B,) per-frame cIoU; 1 where both maps are zero over the region, NaN if the region is empty."""
        iou = torch.where(self.union > 0, self.inter / self.union.clamp(min=1e-300),
                          torch.ones_like(self.union))
        return torch.where(self.valid, iou, torch.full_like(iou, float("nan")))


@dataclass
class PixelTerms:
    """The per-pixel terms of a checked batch, (B, H*W) float32: computed once, summed over every region."""

    sq_err: torch.Tensor     # (P_hat - P)^2, raw prediction
    inter: torch.Tensor      # min(P, clamp(P_hat))
    union: torch.Tensor      # max(P, clamp(P_hat))


def pixel_terms(pred, target, *, name: str = "prediction") -> PixelTerms:
    """Check a batch (pred/target (B,1,H,W): same shape, finite) and compute its per-pixel terms."""
    p, t = _frames(pred, name), _frames(target, "target")
    if p.shape != t.shape:
        raise ValueError(f"{name}: shapes differ: pred {tuple(p.shape)}, target {tuple(t.shape)}")
    for label, x in ((name, p), ("target", t)):
        bad = (~torch.isfinite(x)).any(dim=1).nonzero().flatten().tolist()
        if bad:
            raise ValueError(f"{label}: non-finite values in batch frames {bad[:10]}")
    pc = p.clamp(0.0, 1.0)
    return PixelTerms(sq_err=(p - t) ** 2, inter=torch.minimum(pc, t), union=torch.maximum(pc, t))


def region_scores(terms: PixelTerms, region, *, name: str = "prediction") -> FrameScores:
    """Sum a batch's pixel terms over `region` (B,1,H,W) weights in {0,1}; None: every pixel."""
    if region is None:
        def region_sum(x: torch.Tensor) -> torch.Tensor:
            return x.sum(1, dtype=torch.float64)
        count = torch.full((terms.sq_err.shape[0],), float(terms.sq_err.shape[1]), dtype=torch.float64)
    else:
        r = _frames(region, "region")
        if r.shape != terms.sq_err.shape:
            raise ValueError(f"{name}: shapes differ: pred {tuple(terms.sq_err.shape)}, region {tuple(r.shape)}")
        r = r > 0.5
        zero = torch.zeros((), dtype=terms.sq_err.dtype)

        def region_sum(x: torch.Tensor) -> torch.Tensor:
            # float32 per pixel (half the memory traffic of float64), float64 accumulation
            return torch.where(r, x, zero).sum(1, dtype=torch.float64)
        count = r.sum(1, dtype=torch.float64)
    return FrameScores(sq_err=region_sum(terms.sq_err), count=count, inter=region_sum(terms.inter),
                       union=region_sum(terms.union))


def frame_scores(pred, target, region, *, name: str = "prediction") -> FrameScores:
    """Score a batch: pred/target (B,1,H,W) values, region (B,1,H,W) weights in {0,1}."""
    return region_scores(pixel_terms(pred, target, name=name), region, name=name)


@dataclass
class MapMetrics:
    """Accumulates FrameScores over batches; `result()` gives the reported numbers."""

    rmse_sum: float = 0.0
    ciou_sum: float = 0.0
    frames: int = 0
    skipped: int = 0
    sq_err: float = 0.0
    count: float = 0.0
    inter: float = 0.0
    union: float = 0.0

    def add(self, scores: FrameScores) -> None:
        v = scores.valid
        self.frames += int(v.sum())
        self.skipped += int((~v).sum())
        self.rmse_sum += float(scores.rmse[v].sum())
        self.ciou_sum += float(scores.ciou[v].sum())
        self.sq_err += float(scores.sq_err[v].sum())
        self.count += float(scores.count[v].sum())
        self.inter += float(scores.inter[v].sum())
        self.union += float(scores.union[v].sum())

    def update(self, pred, target, region) -> None:
        self.add(frame_scores(pred, target, region))

    def result(self) -> dict[str, float | int | None]:
        """rmse/ciou (per-frame mean), rmse_pooled/ciou_pooled, frames, skipped.

        With no scored frame at all the values are None (JSON null), never NaN.
        """
        if self.frames == 0:
            return {"rmse": None, "ciou": None, "rmse_pooled": None, "ciou_pooled": None,
                    "frames": 0, "skipped": self.skipped}
        return {
            "rmse": self.rmse_sum / self.frames,
            "ciou": self.ciou_sum / self.frames,
            "rmse_pooled": (self.sq_err / self.count) ** 0.5,
            "ciou_pooled": self.inter / self.union if self.union > 0 else 1.0,
            "frames": self.frames,
            "skipped": self.skipped,
        }


REGIONS = ("f_covered", "f_full", "h_covered", "h_full")


class TrackMetrics:
    """One track's F- metrics (and H- metrics with `holes`), each over covered pixels and
    over the whole canvas / hidden part: `result()` -> {region: MapMetrics.result()}."""

    def __init__(self, holes: bool = False):
        self.holes = holes
        self.regions = {name: MapMetrics() for name in REGIONS if holes or name.startswith("f_")}

    def update(self, pred, target, coverage, mask=None) -> None:
        """pred/target/coverage (B,1,H,W); mask (B,1,H,W) 1 = hidden, required iff `holes`."""
        if self.holes != (mask is not None):
            raise ValueError(f"TrackMetrics(holes={self.holes}) needs {'a' if self.holes else 'no'} hidden-part mask")
        # the per-pixel terms once, summed over each region (they were recomputed per region: 2-4x the work)
        terms = pixel_terms(pred, target)
        coverage = torch.as_tensor(coverage)
        self.regions["f_covered"].add(region_scores(terms, coverage))
        self.regions["f_full"].add(region_scores(terms, None))
        if self.holes:
            mask = torch.as_tensor(mask)
            self.regions["h_covered"].add(region_scores(terms, coverage * mask))
            self.regions["h_full"].add(region_scores(terms, mask))

    def result(self) -> dict[str, dict]:
        return {name: m.result() for name, m in self.regions.items()}
