"""The report's "stats": frames per task / scene / hand, contact-area and pressure histograms."""

from __future__ import annotations

from collections import Counter

import numpy as np

from htdata.format.mapstorage import hand_present
from htdata.format.table import HANDS
from htdata.validate.loaded import Loaded
from htdata.validate.sensors import CONTACT_THRESHOLD, HIST_BINS


def dataset_stats(ds: Loaded, sensor: dict) -> dict:
    """Counts from the index and episode records; histograms over the decoded maps (sensor accumulator)."""
    rows = ds.index
    per_ep = np.bincount(rows["episode"], minlength=len(ds.episodes)) if len(rows) else np.zeros(0, int)
    by_task: Counter = Counter()
    by_scene: Counter = Counter()
    for pos, ep in enumerate(ds.episodes):
        by_task[ep["task"]] += int(per_ep[pos])
        by_scene[ep["scene"]] += int(per_ep[pos])
    area = np.asarray(sensor.get("_contact_area", []), np.float64)
    edges = np.linspace(0.0, 1.0, HIST_BINS + 1)
    return {
        "frames_per_task": dict(sorted(by_task.items())),
        "frames_per_scene": dict(sorted(by_scene.items())),
        "frames_per_hand": {h: int(np.count_nonzero(hand_present(rows, h))) for h in HANDS},
        "contact_area_histogram": {"bin_edges": edges.tolist(),
                                   "counts": np.histogram(area, bins=edges)[0].tolist(),
                                   "threshold": CONTACT_THRESHOLD, "maps": int(area.size)},
        "pressure_histogram": {"bin_edges": edges.tolist(),
                               "counts": np.asarray(sensor.get("_pressure_hist", np.zeros(HIST_BINS)),
                                                    np.int64).tolist(),
                               "note": "covered pixels with value > 0 over decoded maps"},
    }
