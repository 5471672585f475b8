"""Region outlines: the thin boundary lines drawn over every map picture (preview, card, health map)."""

from __future__ import annotations

import numpy as np


def region_outline(labels: np.ndarray) -> np.ndarray:
    """Bool mask of pixels whose right or lower neighbour has another label."""
    edge = np.zeros(labels.shape, bool)
    edge[:, :-1] |= labels[:, :-1] != labels[:, 1:]
    edge[:-1, :] |= labels[:-1, :] != labels[1:, :]
    return edge
