"""The slow rest wander every cell of the sample raw-count glove shows, taxel or gap alike.

Measured on a real two-hand 32x32 knitted glove (issue 34; htdata/synthetic/rawfacts.py
measures the same on the sample glove): a resting cell hardly changes from one
frame to the next (most steps are 0 or half a count), its spread is about a
count (10th-90th percentile ~3 counts), yet it ranges ~1 count over 10 frames,
~3 over 30, ~5 over 100, ~7 over 300 and ~9-10 over 900 frames: it wanders
slowly and now and then bumps up a few counts for a second. Cells without a
sensor wander without the bumps: ~4-5 counts over 300 frames, hardly ever 7.

The model: two Ornstein-Uhlenbeck walks (`WALKS`: stationary std, time
constant) plus bumps (`BUMPS`: events per second per cell, mean height in
counts (exponential, capped), time constant of a smooth rise and fall). State
carries over between chunks, so a long recording drawn in chunks is one walk.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

WALKS = ((0.8, 0.6), (0.8, 20.0))      # (stationary std counts, time constant s)
BUMPS = (1.0 / 6.0, 3.0, 10.0, 0.5)    # (rate per s, mean height, highest, time constant s)


class RestWander:
    """The wander of a (H,W) grid of cells, drawn chunk after chunk; `scale` (H,W) scales each cell's walks and
    `bumps` (H,W) its bumps (0: none)."""

    def __init__(self, scale: np.ndarray, bumps: np.ndarray, rng: np.random.Generator):
        self.scale = np.asarray(scale, np.float32)
        self.bumps = np.asarray(bumps, np.float32)
        shape = self.scale.shape
        # each recording starts anywhere in its walks, with no bump under way
        self.walks = [rng.normal(0.0, std, shape).astype(np.float32) for std, _ in WALKS]
        self.bump_state = [np.zeros((1, *shape), np.float32), np.zeros((1, *shape), np.float32)]

    def next(self, T: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        """(T,H,W) float32: the next T frames, dt seconds apart."""
        shape = self.scale.shape
        out = np.zeros((T, *shape), np.float32)
        for k, (std, tau) in enumerate(WALKS):
            a = float(np.exp(-dt / tau))
            steps = rng.standard_normal((T, *shape), dtype=np.float32) * np.float32(std * np.sqrt(1.0 - a * a))
            walk = lfilter(np.float32([1.0]), np.float32([1.0, -a]), steps, axis=0,
                           zi=(a * self.walks[k])[None])[0]
            self.walks[k] = walk[-1].astype(np.float32)
            out += walk
        out *= self.scale[None]
        rate, mean, top, tau = BUMPS
        hits = rng.random((T, *shape), dtype=np.float32) < np.float32(rate * dt)
        heights = np.minimum(rng.exponential(mean, int(hits.sum())), top).astype(np.float32)
        kicks = np.zeros((T, *shape), np.float32)
        kicks[hits] = heights
        # two one-pole smoothers in a row: a bump rises and falls over ~2 tau; scaled so its top is its height
        a = float(np.exp(-dt / tau))
        n = np.arange(int(20 * tau / dt) + 2)
        b0 = np.float32(1.0 / np.sqrt(((n + 1) * a ** n).max()))
        first, self.bump_state[0] = lfilter([b0], np.float32([1.0, -a]), kicks, axis=0, zi=self.bump_state[0])
        bumps, self.bump_state[1] = lfilter([b0], np.float32([1.0, -a]), first, axis=0, zi=self.bump_state[1])
        out += bumps * self.bumps[None]
        return out
