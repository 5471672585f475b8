"""What a glove feels in the synthetic world: paint (T,H,W) contact grids from a hand state.

Active layout blocks get a Gaussian blob scaled by the task's place intensity
and the grip force; bend cells carry their finger's closure. A layout's
blocks may be `htdata.glove.layouts.Block` objects or plain dicts.
"""

from __future__ import annotations

import numpy as np

from htdata.synthetic.state import HandState
from htdata.synthetic.tasks import FINGERS, GROUPS, PLACE_NAMES, stable_hash


def _block(block) -> tuple[str, str, tuple[int, int], tuple[int, int]]:
    """(name, place, rows, cols) of a layout block given as a dict or an object."""
    get = block.get if isinstance(block, dict) else (lambda k: getattr(block, k))
    return str(get("name")), str(get("place")), tuple(get("rows")), tuple(get("cols"))


def place_intensity(profile: dict[str, float], place: str) -> float:
    """Intensity of a block placed on `place` (a place or a whole group)."""
    if place in GROUPS:
        return max((v for k, v in profile.items() if k.split(".")[0] == place), default=0.0)
    if place not in PLACE_NAMES:
        raise ValueError(f"layout block place {place!r} is not a canonical place or group")
    return profile.get(place, 0.0)


def _block_jitter(jitter_key: int, name: str, t: np.ndarray) -> np.ndarray:
    """(T,2) blob-centre offset in units of the block extent: fixed part + slow drift."""
    rng = np.random.default_rng([jitter_key, stable_hash(name)])
    base = rng.uniform(-0.2, 0.2, 2)
    f, ph = rng.uniform(0.3, 1.0, 2), rng.uniform(0, 2 * np.pi, 2)
    return base[None, :] + 0.08 * np.sin(2 * np.pi * f[None, :] * t[:, None] + ph[None, :])


def _bend_fingers(layout, bend: np.ndarray) -> np.ndarray:
    """Finger index (0..4) of each bend cell: the finger block sharing its column, else -1."""
    out = np.full(len(bend), -1, dtype=np.int64)
    for blk in layout.blocks:
        _, place, _, cols = _block(blk)
        finger = place.split(".")[0]
        if finger in FINGERS:
            inside = (bend[:, 1] >= cols[0]) & (bend[:, 1] <= cols[1])
            out[inside & (out < 0)] = FINGERS.index(finger)
    return out


def contact_grids(layout, state: HandState, fill: float = 0.0) -> np.ndarray:
    """Paint (T,H,W) float32 in [0,1] for a glove `layout` from a hand state.

    Active blocks get a Gaussian blob (centre jittered per episode and block)
    scaled by place intensity x grip force; bend cells get the closure of
    their finger; cells that are neither live nor bend get `fill`
    (NaN for TouchAnything-style "no sensor").
    """
    rows, cols = (int(v) for v in layout.grid)
    T = len(state)
    grid = np.zeros((T, rows, cols), dtype=np.float32)
    profile = state.profile
    for blk in layout.blocks:
        name, place, (r0, r1), (c0, c1) = _block(blk)
        level = place_intensity(profile, place)
        if level <= 0:
            continue
        rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        h, w = r1 - r0 + 1, c1 - c0 + 1
        jit = _block_jitter(state.jitter_key, name, state.t)          # (T,2)
        cy = (r0 + r1) / 2 + jit[:, 0] * h                             # (T,)
        cx = (c0 + c1) / 2 + jit[:, 1] * w
        sy, sx = max(0.55 * h, 0.8), max(0.55 * w, 0.8)
        d2 = ((rr[None] - cy[:, None, None]) / sy) ** 2 + ((cc[None] - cx[:, None, None]) / sx) ** 2
        blob = level * state.force[:, None, None] * np.exp(-0.5 * d2)
        region = grid[:, r0:r1 + 1, c0:c1 + 1]
        np.maximum(region, blob.astype(np.float32), out=region)
    np.clip(grid, 0.0, 1.0, out=grid)
    live = np.asarray(layout.live_mask, dtype=bool)
    bend = np.asarray(layout.bend_cells, dtype=np.int64).reshape(-1, 2)
    keep = live.copy()
    if len(bend):
        finger = _bend_fingers(layout, bend)
        closure = np.concatenate([state.closure, state.closure.mean(axis=1, keepdims=True)], axis=1)
        # Per-cell spread so bend cells of one finger are not identical.
        spread = 0.85 + 0.15 * ((bend[:, 0] * 7 + bend[:, 1] * 3) % 5) / 4.0
        grid[:, bend[:, 0], bend[:, 1]] = np.clip(closure[:, finger] * spread[None, :], 0, 1)
        keep[bend[:, 0], bend[:, 1]] = True
    grid[:, ~keep] = fill
    return grid


def contact_grid(layout, state: HandState, fill: float = 0.0) -> np.ndarray:
    """(H,W) float32 grid for a single-frame state (`HandState.frame(i)`)."""
    if len(state) != 1:
        raise ValueError(f"contact_grid wants a single-frame state, got {len(state)} frames; "
                         "use contact_grids for episodes")
    return contact_grids(layout, state, fill=fill)[0]
