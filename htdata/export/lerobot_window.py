"""`htdata export lerobot --tactile-window K`: every glove row, at the glove's own rate, in LeRobot's frames.

LeRobot stores one row per video frame; a glove sampled at 100-200 Hz beside 30 fps video has
several rows per frame, and `.raw` carries only the one paired with the frame. With a window,
each exported frame also carries the glove rows recorded since the previous exported frame (the
rows of every stored frame after the previous row's frame up to this one: a frame a resampled
export skips gives its rows to the next, a repeated frame gets an empty window, and the last
frame also takes the rows of stored frames after it, dt > 0, where a resampled export ends
early), so each stored row lands in exactly one window. Per raw feature `observation.tactile.<hand>.raw[_RxC]`:

    ....window       float32 (K*rows*cols,): up to K rows, oldest first, each row-major; padding 0
                     (info.window = [K, rows, cols]: reshape restores it)
    ....window_mask  bool (K,): which of the K slots hold a recorded row
    ....window_dt    float32 (K,): each row's time minus the frame's video time, in s (0 where padding)

More rows between two frames than K is an error naming the episode, the frame and the K that
would hold them: rows are never dropped to fit. Flat 1-D features because LeRobot's tooling
takes state features as 1-D vectors (see lerobot_plan.features).
"""

from __future__ import annotations

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.export.lerobot_stats import FeatureStats
from htdata.format.table import JSON_MEMBER, decode_member, raw_member


def window_keys(raw_key: str) -> tuple[str, str, str]:
    """(window, mask, dt) feature names of the raw feature `raw_key` (…raw or …raw_RxC)."""
    base, _, grid = raw_key.rpartition(".raw")
    stem = f"{base}.window{grid}"
    return stem, f"{stem}_mask", f"{stem}_dt"


def check_window(k) -> int | None:
    """--tactile-window's value: None (no window) or an int >= 1."""
    if k is None:
        return None
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ArgumentError(f"--tactile-window must be a whole number >= 1 (rows per frame), got {k!r}")
    return k


def window_features(slots, k: int) -> dict:
    """info.json entries of the window features of every raw slot."""
    feats = {}
    for slot in slots:
        rows, cols = slot.grid
        window, mask, dt = window_keys(slot.key)
        feats[window] = {"dtype": "float32", "shape": [k * rows * cols], "names": None,
                         "info": {"window": [k, rows, cols], "order": "row, then row-major cells",
                                  "units": "raw glove units", "mask": mask, "dt": dt,
                                  "what": "the glove rows recorded since the previous frame, oldest first"}}
        feats[mask] = {"dtype": "bool", "shape": [k], "names": None,
                       "info": {"what": f"which of the {k} slots of {window} hold a recorded row"}}
        feats[dt] = {"dtype": "float32", "shape": [k], "names": None,
                     "info": {"what": f"time of each row of {window} minus the frame's timestamp, s"}}
    return feats


class TiledStats(FeatureStats):
    """Stats of a window feature: per cell over the recorded rows only (padding is not data), repeated
    for each of the K slots so the stats have the feature's shape, as LeRobot's normalisation needs."""

    def __init__(self, k: int):
        super().__init__()
        self.k = k

    def result(self) -> dict | None:
        out = super().result()
        if out is None:
            return None
        return {name: (v if name == "count" else v * self.k) for name, v in out.items()}


class EpisodeWindows:
    """One episode's windows of one raw slot: (frames, K, rows, cols) values, mask and dt."""

    def __init__(self, frames: int, k: int, grid: tuple[int, int]):
        self.k = k
        self.values = np.zeros((frames, k, *grid), np.float32)
        self.mask = np.zeros((frames, k), bool)
        self.dt = np.zeros((frames, k), np.float32)

    def put(self, f: int, rows: list[np.ndarray], t_ns: list[int], t_frame_ns: int, where: str, hand: str) -> None:
        """Frame f's window: `rows` (each (rows, cols)) recorded at `t_ns`, the frame's video time `t_frame_ns`."""
        if len(rows) > self.k:
            raise DatasetError(f"{where}: {len(rows)} {hand} glove rows were recorded since the previous frame; "
                               f"--tactile-window {self.k} holds {self.k}: pass --tactile-window {len(rows)} or "
                               f"more (rows are never dropped to fit)")
        for slot, (row, t) in enumerate(zip(rows, t_ns)):
            # NaN / Inf mark cells without a taxel in some sources: 0, as in the .raw feature
            self.values[f, slot] = np.where(np.isfinite(row), row, 0.0)
            self.mask[f, slot] = True
            self.dt[f, slot] = (int(t) - int(t_frame_ns)) / 1e9

    def columns(self, raw_key: str) -> dict[str, np.ndarray]:
        window, mask, dt = window_keys(raw_key)
        n = len(self.values)
        return {window: self.values.reshape(n, -1), mask: self.mask, dt: self.dt}

    def add_stats(self, stats: dict, raw_key: str) -> None:
        window, mask, dt = window_keys(raw_key)
        real = self.values[self.mask]                       # (rows recorded, rows, cols)
        if len(real):
            stats[window].add_episode(real.reshape(len(real), -1))
            stats[dt].add_episode(self.dt[self.mask.any(axis=1)])
        if len(self.mask):
            stats[mask].add_episode(self.mask)


def sample_rows(members: dict, hand: str, where: str) -> tuple[list[np.ndarray], list[int]]:
    """Every glove row a stored frame holds for `hand`, with its recorded time (none: an RGB-only frame)."""
    if raw_member(hand) not in members:
        return [], []
    rows = decode_member(raw_member(hand), members[raw_member(hand)], where)
    meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], where)
    times = list((meta.get("raw_t_ns") or {}).get(hand) or [])
    if rows.ndim != 3 or len(times) != rows.shape[0]:
        raise DatasetError(f"{where}: {len(times)} raw_t_ns times for {hand} raw rows shaped {rows.shape}")
    return list(rows), [int(t) for t in times]
