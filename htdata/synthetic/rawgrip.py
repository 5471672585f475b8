"""How a hand presses the sample raw-count glove: a grip as a few small pressed patches, in counts, over time.

What the real knitted glove shows (issue 34) and this copies: a grip presses
a few tens of the ~690 live cells, most of them by 15-60 counts above their
rest and a few by hundreds (up to saturation), so the mean over all live
cells moves by only a few counts; the pressed area is patches on the palm,
the finger strips and the thumb that wobble as the grip works (a knife saws,
a pitcher tilts); a few cells beside a patch are stretched and read BELOW
their rest instead of rising; the working hand of a knife clip grips nearly
the whole clip, the other hand steadies the food now and then.

A grip is `GripPlan`: patches (Gaussian, centre wobbling), hot cells (one
cell pressed hard), a broad shallow rise under the palm, sink cells (beside
a patch, falling), and the intervals the hand holds on. `press_field`
evaluates it: (T,32,32) press in counts (>= 0, the truth) and (T,32,32)
falls in counts (<= 0, sink cells only, where press is 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import binary_dilation

from htdata.synthetic.rawlayout import FINGER_ROWS, GRID, SEGMENT_COLS, sensor_mask
from htdata.synthetic.tasks import stable_hash

RAMP_S = 0.35            # seconds a grip takes to close or open
TAIL = 0.5               # press below this (counts) is none: a patch's far tail
SINK_DROP = (8.0, 18.0)  # counts a stretched cell beside a patch falls
SWING = (0.8, 1.0)       # a patch's press comes and goes by this share as the grip shifts ...
SWING_HZ = (0.05, 0.3)   # ... this often
ROAM = (2.0, 5.0)        # cells a patch slides over a clip ...
ROAM_HZ = (0.03, 0.1)    # ... this slowly
SPREAD = (8.0, 14.0)     # counts of the broad shallow rise around a power grip (sigma SPREAD_SIGMA cells)
SPREAD_SIGMA = (4.0, 6.0)


@dataclass
class Patch:
    row: float
    col: float
    sy: float            # Gaussian sigma along raw rows / columns, cells
    sx: float
    peak: float          # counts at the centre, full grip
    wobble: float        # cells the centre wanders as the grip works
    freq: float          # Hz of that wander
    phase: float
    swing: float = 0.0   # share of its press the patch loses and regains as the grip shifts ...
    swing_hz: float = 0.1  # ... at this rate
    span: int = -1       # presses only during this span of the plan (-1: during every span)
    roam: tuple[float, float] = (0.0, 0.0)   # cells the centre slides over the clip (rows, cols) ...
    roam_hz: float = 0.05                    # ... this slowly (the hand shifts on the handle)


@dataclass
class GripPlan:
    """One hand's presses in one clip (module docstring)."""
    patches: list[Patch] = field(default_factory=list)
    hot: list[tuple[int, int, float]] = field(default_factory=list)     # (row, col, extra counts)
    sinks: list[tuple[int, int, float]] = field(default_factory=list)   # (row, col, counts it falls)
    spans: list[tuple[float, float]] = field(default_factory=list)      # (on, off) seconds; off may pass the end
    spread: tuple[float, float, float, float] | None = None              # broad rise: (peak, row, col, sigma)
    work_hz: float = 1.0       # the grip's force swings at this rate ...
    work_depth: float = 0.2    # ... by this share


# Where patches go, raw (rows, cols) boxes of centres: palm, each finger's segments, thumb tip / base.
PALM_CENTRES = ((2.0, 21.0), (2.0, 17.0))
THUMB_TIP, THUMB_BASE = ((28.5, 30.5), (7.5, 11.5)), ((23.5, 26.5), (7.5, 11.5))


def _lognormal(rng: np.random.Generator, median: float, sigma: float, low: float, high: float) -> float:
    return float(np.clip(median * np.exp(sigma * rng.standard_normal()), low, high))


def _patch(rng, rows, cols, sy, sx, peak, sigma=0.35) -> Patch:
    return Patch(float(rng.uniform(*rows)), float(rng.uniform(*cols)), float(rng.uniform(*sy)),
                 float(rng.uniform(*sx)), _lognormal(rng, peak, sigma, 18.0, 160.0),
                 float(rng.uniform(0.2, 0.6)), float(rng.uniform(0.2, 0.9)), float(rng.uniform(0, 2 * np.pi)),
                 float(rng.uniform(*SWING)), float(rng.uniform(*SWING_HZ)),
                 roam=(float(rng.uniform(*ROAM)), float(rng.uniform(*ROAM))), roam_hz=float(rng.uniform(*ROAM_HZ)))


def _finger_patch(rng, finger: str, segment: str, peak: float) -> Patch:
    r0, r1 = FINGER_ROWS[finger]
    c0, c1 = SEGMENT_COLS[segment]
    p = _patch(rng, (r0 + 1.0, r1 - 1.0), (c0 + 0.5, c1 - 0.5), (0.9, 1.3), (1.3, 2.0), peak)
    p.roam = (float(rng.uniform(0.0, 0.5)), float(rng.uniform(*ROAM)))      # along the strip
    return p


def _power(rng, seg: str, fingers: float, palm: int, peak: float) -> GripPlan:
    """A handle in the fist (knife, pitcher): palm patches, the fingers' `seg` segments, the thumb tip."""
    g = GripPlan()
    g.patches += [_patch(rng, *PALM_CENTRES, (1.3, 1.9), (1.3, 1.9), peak) for _ in range(palm)]
    for finger in FINGER_ROWS:
        if rng.random() < fingers:
            g.patches.append(_finger_patch(rng, finger, seg if rng.random() < 0.7 else "proximal", peak))
    g.patches.append(_patch(rng, *THUMB_TIP, (0.9, 1.3), (1.2, 1.7), peak))
    if rng.random() < 0.5:
        g.patches.append(_patch(rng, *THUMB_BASE, (1.0, 1.4), (1.2, 1.7), 0.7 * peak))
    palm = g.patches[0]
    g.spread = (float(rng.uniform(*SPREAD)), palm.row, palm.col, float(rng.uniform(*SPREAD_SIGMA)))
    return g


def _pinch(rng, peak: float) -> GripPlan:
    g = GripPlan()
    g.patches += [_finger_patch(rng, "index", "distal", peak), _patch(rng, *THUMB_TIP, (1.0, 1.4), (1.4, 1.9), peak)]
    if rng.random() < 0.6:
        g.patches.append(_finger_patch(rng, "middle", "distal", peak))
    g.patches.append(_patch(rng, *PALM_CENTRES, (1.2, 1.6), (1.2, 1.6), 0.6 * peak))   # the palm meets it too
    return g


def _steady(rng, peak: float, duration_s: float) -> GripPlan:
    """The other hand steadying the food now and then: each time one or two light patches, somewhere else."""
    g = GripPlan()
    t = float(rng.uniform(0.5, 3.0))
    while t < duration_s:
        hold = float(rng.uniform(1.5, 5.0))
        touch = [_patch(rng, *PALM_CENTRES, (1.0, 1.6), (1.0, 1.6), peak, sigma=0.3)]
        if rng.random() < 0.6:
            finger = tuple(FINGER_ROWS)[int(rng.integers(len(FINGER_ROWS)))]
            touch.append(_finger_patch(rng, finger, ("distal", "middle")[int(rng.integers(2))], peak))
        elif rng.random() < 0.5:
            touch.append(_patch(rng, *THUMB_TIP, (0.9, 1.3), (1.2, 1.7), peak))
        for p in touch:
            p.span = len(g.spans)
        g.patches += touch
        g.spans.append((t, t + hold))
        t += hold + float(rng.uniform(1.5, 6.0))
    return g


# task -> (working hand's grip, its patches' peak median (counts), palm patches, share of fingers on the object,
#          the other hand's peak median (None: it rests), the grip's force swing in Hz)
TASKS = {
    "slice": ("power", 40.0, 2, 0.9, 28.0, 1.2),
    "peel": ("power", 38.0, 2, 0.9, 32.0, 0.8),
    "pour": ("power", 48.0, 1, 0.9, None, 0.3),
    "power_grasp": ("power", 40.0, 2, 0.75, 24.0, 0.5),
    "pinch_pick": ("pinch", 45.0, 1, 0.0, None, 0.5),
    "palm_push": ("palm", 45.0, 3, 0.0, None, 0.4),
}
HELD = ("slice", "peel")   # knife clips: the working hand grips nearly the whole clip


def plan_hand(task: str, role: str, start: str, duration_s: float, seed: int, hand: str) -> GripPlan:
    """The grip of one hand ("working" or "support") in one clip; start "rest" or "mid_grasp"."""
    if task not in TASKS:
        raise ValueError(f"unknown raw-glove task {task!r}; known: {', '.join(TASKS)}")
    kind, peak, palm, fingers, support_peak, hz = TASKS[task]
    rng = np.random.default_rng([seed & 0xFFFFFFFF, stable_hash("rawgrip"), stable_hash(hand), stable_hash(role)])
    if role == "support":
        if support_peak is None:
            return GripPlan()
        g = _steady(rng, support_peak, duration_s)
    else:
        if kind == "power":
            g = _power(rng, "middle" if task == "pour" else "proximal", fingers, palm, peak)
        elif kind == "pinch":
            g = _pinch(rng, peak)
        else:
            g = GripPlan(patches=[_patch(rng, *PALM_CENTRES, (1.5, 2.0), (1.5, 2.0), peak) for _ in range(palm)])
        if task in HELD:
            on = 0.0 if start == "mid_grasp" else float(rng.uniform(0.5, 1.2))
            off = duration_s - float(rng.uniform(0.1, 0.5))
        elif start == "mid_grasp":
            on, off = 0.0, duration_s * float(rng.uniform(0.55, 0.8))
        else:
            on, off = duration_s * float(rng.uniform(0.15, 0.3)), duration_s * float(rng.uniform(0.7, 0.85))
        g.spans = [(on, off)]
        _add_hot_cells(g, rng)
    g.work_hz, g.work_depth = hz * float(rng.uniform(0.8, 1.25)), float(rng.uniform(0.12, 0.25))
    _add_sinks(g, rng)
    return g


def _footprint(g: GripPlan) -> np.ndarray:
    """(32,32) bool: cells a full grip presses by >= 15 counts (patch centres at rest)."""
    rr, cc = np.mgrid[0:GRID[0], 0:GRID[1]]
    press = sum((p.peak * np.exp(-0.5 * (((rr - p.row) / p.sy) ** 2 + ((cc - p.col) / p.sx) ** 2))
                 for p in g.patches), np.zeros(GRID))
    return (press >= 15.0) & sensor_mask()


def _add_hot_cells(g: GripPlan, rng: np.random.Generator) -> None:
    """Two cells of the footprint pressed far deeper (an edge of the handle): hundreds of counts, one up to
    saturation."""
    cells = np.argwhere(_footprint(g))
    if not len(cells):
        return
    for k, i in enumerate(rng.choice(len(cells), size=min(len(cells), 2), replace=False)):
        extra = float(rng.uniform(300.0, 470.0)) if k == 0 else _lognormal(rng, 120.0, 0.5, 50.0, 300.0)
        g.hot.append((int(cells[i][0]), int(cells[i][1]), extra))


def _add_sinks(g: GripPlan, rng: np.random.Generator) -> None:
    """A few sensor cells just outside the footprint that a grip stretches: they fall instead of rising."""
    foot = _footprint(g)
    ring = np.argwhere(binary_dilation(foot, np.ones((3, 3), bool)) & ~foot & sensor_mask())
    if not len(ring):
        return
    n = min(len(ring), int(rng.poisson(0.7 * len(g.patches))))
    for i in rng.choice(len(ring), size=n, replace=False):
        g.sinks.append((int(ring[i][0]), int(ring[i][1]), float(rng.uniform(*SINK_DROP))))


def envelope(g: GripPlan, t: np.ndarray, span: int = -1) -> np.ndarray:
    """(T,) grip strength in [0, ~1.25]: on inside a span (or only `span`; RAMP_S ramps; a span from 0 is on at
    frame 0)."""
    env = np.zeros(len(t))
    for on, off in (g.spans if span < 0 else g.spans[span:span + 1]):
        up = np.ones(len(t)) if on <= 0 else np.clip((t - on) / RAMP_S, 0.0, 1.0)
        down = np.clip((off - t) / RAMP_S, 0.0, 1.0)
        env = np.maximum(env, up * down)
    env = env * env * (3.0 - 2.0 * env)                       # smoothstep
    return env * (1.0 + g.work_depth * np.sin(2 * np.pi * g.work_hz * t))


def _window(centre: np.ndarray, sigma: float, size: int) -> slice:
    reach = 3.5 * sigma
    return slice(max(0, int(np.floor(centre.min() - reach))), min(size, int(np.ceil(centre.max() + reach)) + 1))


def press_field(g: GripPlan, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((T,32,32) press >= 0, (T,32,32) fall <= 0), float32 counts, at times t (seconds from the clip start)."""
    T = len(t)
    press = np.zeros((T, *GRID), np.float32)
    fall = np.zeros((T, *GRID), np.float32)
    env = envelope(g, t)
    if not g.patches or not env.any():
        return press, fall
    for p in g.patches:
        wob = p.wobble * np.sin(2 * np.pi * p.freq * t + p.phase)
        slide = np.sin(2 * np.pi * p.roam_hz * t + 3 * p.phase)
        cy, cx = p.row + wob + p.roam[0] * slide, p.col + 0.7 * wob + p.roam[1] * np.cos(2 * np.pi * p.roam_hz * t)
        ys, xs = _window(cy, p.sy, GRID[0]), _window(cx, p.sx, GRID[1])
        gy = np.exp(-0.5 * ((np.arange(ys.start, ys.stop)[None] - cy[:, None]) / p.sy) ** 2).astype(np.float32)
        gx = np.exp(-0.5 * ((np.arange(xs.start, xs.stop)[None] - cx[:, None]) / p.sx) ** 2).astype(np.float32)
        shift = 1.0 - p.swing * (0.5 + 0.5 * np.sin(2 * np.pi * p.swing_hz * t + 2 * p.phase))
        force = p.peak * (env if p.span < 0 else envelope(g, t, p.span)) * shift
        press[:, ys, xs] += force.astype(np.float32)[:, None, None] * gy[:, :, None] * gx[:, None, :]
    if g.spread:
        peak, row, col, sigma = g.spread
        rr, cc = np.mgrid[0:GRID[0], 0:GRID[1]]
        broad = np.exp(-0.5 * ((rr - row) ** 2 + (cc - col) ** 2) / sigma ** 2).astype(np.float32)
        press += (peak * env).astype(np.float32)[:, None, None] * broad[None]
    for r, c, extra in g.hot:
        press[:, r, c] += np.float32(extra) * env.astype(np.float32)
    press[press < TAIL] = 0.0
    press *= sensor_mask()[None]
    for r, c, drop in g.sinks:
        press[:, r, c] = 0.0
        fall[:, r, c] = -np.float32(drop) * np.minimum(env, 1.0).astype(np.float32)
    return press, fall
