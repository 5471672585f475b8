"""LeRobot's meta/stats.json numbers, gathered while exporting (one pass, mergeable across episodes).

Keys per feature as LeRobot writes them: min, max, mean, std, count, q01, q10, q50, q90, q99.
Non-video features: per element; sums exact, quantiles exact per episode and frame-weighted
across episodes (the way LeRobot aggregates per-episode stats). Video features: per channel in
[0,1] units, shape (C,1,1), exact from 256-bin histograms of the uint8 frames.
"""

from __future__ import annotations

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)


class FeatureStats:
    """Mergeable per-element stats of one non-video feature (sums exact, quantiles per episode)."""

    def __init__(self):
        self.count = 0
        self.sum = self.sumsq = self.min = self.max = None
        self.qsum = None               # frame-weighted sum of per-episode quantiles

    def add_episode(self, values: np.ndarray) -> None:
        """Add one episode's values (N, ...): one row per frame; an empty episode adds nothing."""
        if len(values) == 0:
            return
        x = np.asarray(values, np.float64)
        n = len(x)
        q = np.quantile(x, QUANTILES, axis=0)
        if self.sum is None:
            self.sum, self.sumsq = x.sum(0), (x * x).sum(0)
            self.min, self.max, self.qsum = x.min(0), x.max(0), q * n
        else:
            self.sum += x.sum(0)
            self.sumsq += (x * x).sum(0)
            self.min, self.max = np.minimum(self.min, x.min(0)), np.maximum(self.max, x.max(0))
            self.qsum += q * n
        self.count += n

    def result(self) -> dict | None:
        """LeRobot's stats of the feature as lists (min, max, mean, std, count, q01..q99); None when empty."""
        if not self.count:
            return None
        mean = self.sum / self.count
        std = np.sqrt(np.maximum(self.sumsq / self.count - mean * mean, 0.0))
        out = {"min": self.min, "max": self.max, "mean": mean, "std": std, "count": np.array([self.count])}
        for q, v in zip(QUANTILES, self.qsum / self.count):
            out[_qname(q)] = v
        return {k: np.atleast_1d(v).tolist() for k, v in out.items()}


class VideoStats:
    """Per-channel stats of uint8 frames in [0,1] units, shape (C,1,1) as LeRobot stores image stats."""

    def __init__(self, channels: int = 3):
        self.hist = np.zeros((channels, 256), np.int64)
        self.frames = 0

    def add(self, frame: np.ndarray) -> None:
        """Add one (H, W, C) uint8 frame."""
        for c in range(self.hist.shape[0]):
            self.hist[c] += np.bincount(frame[..., c].ravel(), minlength=256)
        self.frames += 1

    def result(self) -> dict | None:
        """LeRobot's image stats as (C,1,1) lists in [0,1] units, with the frame count; None without frames."""
        if not self.frames:
            return None
        levels = np.arange(256) / 255.0
        total = self.hist.sum(1)
        mean = (self.hist * levels).sum(1) / total
        std = np.sqrt(np.maximum((self.hist * levels ** 2).sum(1) / total - mean ** 2, 0.0))
        nz = [np.flatnonzero(h) for h in self.hist]
        out = {"min": [levels[z[0]] for z in nz], "max": [levels[z[-1]] for z in nz], "mean": mean, "std": std}
        cdf = np.cumsum(self.hist, 1) / total[:, None]
        for q in QUANTILES:
            out[_qname(q)] = [levels[int(np.searchsorted(c, q))] for c in cdf]
        shaped = {k: np.asarray(v, np.float64).reshape(-1, 1, 1).tolist() for k, v in out.items()}
        shaped["count"] = [self.frames]
        return shaped


def _qname(q: float) -> str:
    return f"q{int(round(q * 100)):02d}"


