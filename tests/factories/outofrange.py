"""Recordings whose raw values leave the glove's range (an OpenTouch scene with -500 and 1e9 cells, a
TouchAnything episode with a value above 1): shared by the out-of-range and console tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.glove.layouts import load_layout
from htdata.synthetic.formats import (
    TouchAnythingEpisode,
    write_opentouch_annotations,
    write_opentouch_scene,
    write_touchanything_episode,
)
from tests.factories import COLOURS, ot_clip


def opentouch_raw(root: Path) -> Path:
    """demo_01: clean; demo_02: -500 at frame 2 (3 taxels) and 1e9 at frames 5,6 (1 taxel each) of 10."""
    clean = np.full((8, 16, 16), 2000.0, np.float32)
    hostile = np.full((10, 16, 16), 2000.0, np.float32)
    hostile[2, 0, :3] = -500.0
    hostile[5, 3, 3] = 1e9
    hostile[6, 4, 4] = 1e9
    write_opentouch_scene(root / "kitchen.hdf5", [ot_clip("demo_01", 8, COLOURS[0], pressure=clean),
                                                  ot_clip("demo_02", 10, COLOURS[1], pressure=hostile)])
    write_opentouch_annotations(root / "annotations.csv", [{"id": "kitchen::demo_01", "action": "pour"},
                                                           {"id": "kitchen::demo_02", "action": "cut"}])
    return root


def live_taxels(layout_id: str) -> np.ndarray:
    return np.argwhere(load_layout(layout_id).live_mask)


def ta_episode(folder: Path, t: int, *, left=True, left_value=None, right_value=None) -> None:
    grids = {}
    for hand, value in (("left", left_value), ("right", right_value)):
        lay = load_layout(f"touchanything_{hand}_21x21")
        g = np.full((t, 21, 21), np.nan, np.float32)
        g[:, lay.live_mask] = 0.5 if value is None else np.float32(0.5)
        if value is not None:
            r, c = live_taxels(f"touchanything_{hand}_21x21")[0]
            g[1, r, c] = value
        grids[hand] = g
    ep = TouchAnythingEpisode(left_grid=grids["left"] if left is True else
                              (np.full((t, 21, 21), np.nan, np.float32) if left == "nan" else None),
                              right_grid=grids["right"],
                              chest_frames=[np.full((480, 640, 3), COLOURS[0], np.uint8)] * t,
                              ts_epoch_s=1.7e9 + np.arange(t) / 30.0)
    write_touchanything_episode(folder, ep, wrist_videos=False)
