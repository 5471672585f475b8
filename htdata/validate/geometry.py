"""Per-layout pixel lookups (covered pixels, their regions) that the content and sensor checks share."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class CoverageGeometry:
    """Per-layout lookups computed once per shard, so each map costs a few vector ops."""
    mask: np.ndarray        # (224,224) bool covered pixels
    idx: np.ndarray         # flat indices of covered pixels
    labels: np.ndarray      # region id of each covered pixel (0 = outside every region)
    counts: np.ndarray      # covered pixels per region id
    n_covered: int


def coverage_geometry(coverage: np.ndarray, region_map: np.ndarray | None) -> CoverageGeometry:
    mask = np.asarray(coverage, bool)
    idx = np.flatnonzero(mask.ravel())
    regions = np.zeros(mask.shape, np.uint8) if region_map is None else region_map
    labels = regions.ravel()[idx].astype(np.intp)
    counts = np.bincount(labels, minlength=int(regions.max()) + 1)
    return CoverageGeometry(mask, idx, labels, counts, int(idx.size))


def coverage_geometries(coverage: dict[str, np.ndarray], region_map: np.ndarray | None
                        ) -> dict[str, CoverageGeometry]:
    """hand_key -> geometry; hands sharing one coverage array (one layout) share one geometry."""
    by_array: dict[int, CoverageGeometry] = {}
    for cov in coverage.values():
        if id(cov) not in by_array:
            by_array[id(cov)] = coverage_geometry(cov, region_map)
    return {k: by_array[id(cov)] for k, cov in coverage.items()}
