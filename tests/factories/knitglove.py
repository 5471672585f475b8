"""A 16x16 raw-count knit glove like a real one (rest ~550 counts with per-taxel offsets, noise of
3 counts, presses of +150..+400 counts), its first-draft layout (forgets the thumb strip) and a
glove-only native recording of it: shared by the unmapped-cell, layout-name and health tests.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording

GRID = (16, 16)
REST, NOISE = 550.0, 3.0


def draft_layout(layout_id: str = "knit_right_16x16", unused: list | None = None) -> dict:
    doc = {"layout_id": layout_id, "hand": "right", "grid": list(GRID),
           "value": {"convention": "direct", "max": 1023, "step": 1},
           "blocks": [{"name": "index_tip", "place": "index.distal", "rows": [0, 3], "cols": [0, 3]},
                      {"name": "palm", "place": "palm", "rows": [8, 15], "cols": [0, 15]}],
           "dead_cells": [], "bend_cells": [], "source": "tests/factories/knitglove.py"}
    if unused is not None:
        doc["unused_cells"] = unused
    return doc


def knit_counts(frames: int = 240, seed: int = 0, rest_shift: float = 0.0) -> np.ndarray:
    """(T,16,16) integer raw counts: every cell rests with noise; index tip, palm and thumb get presses.

    The per-taxel offsets belong to the glove (same for every seed); `rest_shift` moves the whole rest
    level, as a glove's rest level differs between recordings.
    """
    offsets = np.random.default_rng(1234).uniform(-25, 25, GRID) + rest_shift
    rng = np.random.default_rng(seed)
    raw = REST + offsets + rng.normal(0, NOISE, (frames, *GRID))
    t = np.arange(frames)
    press = np.clip(np.sin(2 * np.pi * t / 80.0), 0, None)            # presses, then rests
    live_regions = [(slice(0, 4), slice(0, 4)), (slice(8, 16), slice(0, 16)), (slice(0, 4), slice(10, 16))]
    for rows, cols in live_regions:
        depth = rng.uniform(150, 400, raw[0, rows, cols].shape)
        raw[:, rows, cols] += press[:, None, None] * depth[None]
    return np.clip(np.round(raw), 0, 1023).astype(np.float16).astype(np.float32)


def write_glove_only(folder: Path, layout: str, values: np.ndarray) -> Path:
    ts = np.arange(len(values), dtype=np.int64) * 33_333_333
    rec = NativeRecording(task="hold_pitcher", scene="lab", video_frames=[], video_timestamps_ns=np.zeros(0, np.int64),
                          video_storage="none", hands={"right": NativeHand(layout, values, ts)})
    write_native_recording(folder, rec)
    return folder
