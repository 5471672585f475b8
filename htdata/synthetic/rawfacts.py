"""What a raw-count glove recording shows, measured from the counts alone: rest, offsets, wander, grips, cross-talk.

One measure for both the sample raw-count glove (htdata/synthetic/rawglove.py)
and real recordings of a glove (given as arrays by the caller; the toolkit
never reads a real recording here), so the two can be compared number for
number (tests/synthetic/test_rawglove_facts.py, `tools/rawglove_facts.py`).

Per (clip, hand), with raw counts `raw` (T,H,W) and a layout's live cells:
- pressed: raw minus the cell's own 10th percentile over the clip > PRESSED
  counts (the truth of the real-glove measures); contact frame: >= CONTACT_CELLS
  pressed cells;
- resting cells: live cells never pressed in the clip; gaps: cells outside
  every block that are not in a cross-talk column (a column with no live cell);
- rest level: the median over resting cells of their 10th percentile; offset
  spread: how far those per-cell levels sit from it (p5..p95 width, max - min);
- wander: a resting cell's range (max - min) over the clip, and over each
  WANDER_WINDOW-frame window (clips differ in length: a short clip shows
  little wander); fast step: the median |frame-to-frame change|;
- grip: the clip's working hand is the hand with more pressed cell-frames;
  its pressed cells per contact frame (median), and its mean-level shift: the
  95th percentile of the mean over live cells minus the median of that mean
  over the REST_SHARE frames with the lowest mean;
- press depth: per cell pressed at some frame, its highest rise over its 10th
  percentile (median, p90, deepest per (clip, hand));
- below-rest neighbours: a cell's own rest is its median over the REST_SHARE
  frames with the lowest mean; of the live cells next to (8-neighbours) a cell
  that rises > PRESSED over its rest, and never rising so themselves, the
  share that fall >= FALL counts below their rest in a contact frame;
- cross-talk column: its cells' range, and whether they rise and fall;
- mid-grasp start: >= 15 pressed cells on average in frames 0-29 and >= 10
  more than in the clip's least-pressed 30-frame window; a held clip: contact
  in >= HELD_SHARE of the frames;
- saturation: the highest count; the value step: the smallest gap between
  distinct values;
- over all clips of a hand: the bounding box of the largest 4-connected group
  of cells that move (range > MOVING) in some clip.

`corpus_facts` pools the rows; `FACTS` states the real glove's facts as ranges
and `fact_failures` lists the pooled numbers outside them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_dilation, label

from htdata.glove.layouts import parse_layout
from htdata.synthetic.rawglove import corpus_clips, glove_layout

# The real-glove measures' truth (the README of the real-glove folder a caller names), one home for the facts below, the
# real-glove bench (benchmarks/realglove.py, version 1) and version 2 (benchmarks/realglovev2.py).
PRESSED = 15.0          # counts over the cell's rest (v1: its own 10th percentile): pressed
QUIET = 5.0             # ... below this: quiet
TRUTH_PERCENTILE = 10.0  # the percentile a cell's rest is taken at
CONTACT_CELLS = 7       # pressed cells that make a contact frame
REST_SHARE = 0.10       # the lowest-mean share of frames taken as the hand's rest
START_FRAMES = 30       # a clip's first second: where a mid-grasp start is looked for
MID_GRASP = 15.0        # ... with at least this many pressed cells on average
MID_GRASP_GAIN = 10.0   # ... and this many more than in the clip's quietest second
FALL = 10.0             # counts below the cell's rest that count as falling
WANDER_WINDOW = 300     # frames (10 s at 30 fps)
HELD_SHARE = 0.85       # contact in this share of a clip's frames: held nearly all along
MOVING = 20.0           # a cell whose range over a clip exceeds this moves
FULL_SCALE = 1023.0


@dataclass(frozen=True)
class FactRange:
    """A fact of the real glove as a closed range of one pooled number."""
    key: str
    low: float
    high: float
    says: str


# The real glove's facts (a two-hand 32x32 knitted glove, raw counts 0-1023, 30 fps) as ranges of the pooled
# numbers of `corpus_facts`. Rest levels per hand; the grip facts over the working hands.
FACTS = (
    FactRange("rest_left", 553.0, 561.0, "rest sits at ~557 counts (left)"),
    FactRange("rest_right", 562.0, 570.0, "rest sits at ~566 counts (right)"),
    FactRange("offset_range_p50", 10.0, 99.0, "per-cell offsets of tens of counts (max - min over resting cells)"),
    FactRange("fine_step", 0.25, 0.5, "float16 values: 0.25-0.5 count steps"),
    FactRange("wander_window_p50", 3.0, 12.0, "every resting cell wanders several counts over a clip (300 frames)"),
    FactRange("gap_wander_window_p50", 2.0, 12.0, "gaps wander too"),
    FactRange("fast_step_p50", 0.0, 0.5, "... slowly: frame-to-frame steps of half a count at most (median)"),
    FactRange("grip_cells_min", 25.0, 75.0, "a grip presses 25-75 of ~690 live cells (fewest of the working hands)"),
    FactRange("grip_cells_max", 25.0, 75.0, "a grip presses 25-75 of ~690 live cells (most of the working hands)"),
    FactRange("grip_shift_min", 0.6, 12.5, "a grip moves the mean over live cells by 0.6-12.5 counts (fewest)"),
    FactRange("grip_shift_max", 0.6, 12.5, "... (<= 0.012 of full scale; most)"),
    FactRange("depth_max", 300.0, 470.0, "presses reach ~460 counts"),
    FactRange("saturation", 1015.0, 1023.0, "saturation ~1020"),
    FactRange("moving_box", 0.7 * 32 * 32, 32 * 32, "one connected sensor: a box around connected moving cells "
                                                    "covers most of the grid (cells, the hand with the largest)"),
    FactRange("below_rest_share", 0.005, 0.3, "some cells beside a pressed area fall below rest"),
    FactRange("crosstalk_moving_share", 0.05, 1.0, "the cross-talk column moves (share of its cells ranging > 20)"),
    FactRange("crosstalk_falls", 1.0, 1.0, "the cross-talk column also falls below rest"),
    FactRange("mid_grasp_clips", 1.0, 1e9, "some clips start mid-grasp"),
    FactRange("held_clips", 1.0, 1e9, "in some clips the working hand grips nearly the whole clip"),
)


def _ptp(a: np.ndarray) -> np.ndarray:
    return a.max(axis=0) - a.min(axis=0) if len(a) else np.zeros(a.shape[1:], a.dtype)


def _window_ranges(cells: np.ndarray) -> np.ndarray:
    """(cells,) median range over WANDER_WINDOW-frame windows (half-overlapping; the whole clip when shorter)."""
    T = len(cells)
    if T <= WANDER_WINDOW:
        return _ptp(cells)
    starts = range(0, T - WANDER_WINDOW + 1, WANDER_WINDOW // 2)
    return np.median(np.stack([_ptp(cells[a:a + WANDER_WINDOW]) for a in starts]), axis=0)


def hand_facts(raw: np.ndarray, live: np.ndarray) -> dict:
    """The measures of one (clip, hand): raw (T,H,W) counts, live (H,W) the layout's live cells (module docstring).

    Long because it is one table of measures over the same intermediate arrays; split, each part would need them all.
    """
    raw = np.asarray(raw, np.float32)
    live = np.asarray(live, bool)
    T = len(raw)
    p10 = np.percentile(raw, 10, axis=0)
    rise = raw - p10
    pressed = (rise > PRESSED) & live[None]
    n_pressed = pressed.sum(axis=(1, 2))
    ever = pressed.any(axis=0)
    resting = live & ~ever & (_ptp(raw) > 0)            # constant cells (dead, stuck, saturated) are no rest
    crosstalk = ~live.any(axis=0)                       # columns with no live cell
    xcol = np.zeros(live.shape, bool)
    xcol[:, crosstalk] = True
    gaps = ~live & ~xcol & (rise.max(axis=0) <= PRESSED)
    contact = n_pressed >= CONTACT_CELLS
    mean = raw[:, live].mean(axis=1)
    rest_frames = np.argsort(mean, kind="stable")[:max(1, int(round(REST_SHARE * T)))]
    rest_cell = np.median(raw[rest_frames], axis=0)
    rest = float(np.median(p10[resting])) if resting.any() else float("nan")
    offsets = p10[resting] - rest
    steps = np.abs(np.diff(raw[:, resting], axis=0))
    above = live & ((raw - rest_cell).max(axis=0) > PRESSED)   # rises over its own rest (a fall is no press here)
    near = binary_dilation(above, np.ones((3, 3), bool)) & ~above & live
    below = np.zeros(live.shape, bool)
    if contact.any():
        below = near & ((raw[contact] - rest_cell).min(axis=0) <= -FALL)
    depths = rise.max(axis=0)[ever].astype(np.float32)
    x = raw[:, xcol]
    x_rest = rest_cell[xcol]
    windows = [n_pressed[a:a + 30].mean() for a in range(0, max(T - 29, 1))]
    values = np.unique(raw)
    return {
        "frames": T, "live": int(live.sum()),
        "rest": rest, "offset_p5_p95": float(np.subtract(*np.percentile(offsets, [95, 5]))) if len(offsets) else None,
        "offset_range": float(np.ptp(offsets)) if len(offsets) else None,
        "wander": float(np.median(_ptp(raw[:, resting]))) if resting.any() else None,
        "wander_window": float(np.median(_window_ranges(raw[:, resting]))) if resting.any() else None,
        "gap_wander_window": float(np.median(_window_ranges(raw[:, gaps]))) if gaps.any() else None,
        "fast_step": float(np.median(steps)) if steps.size else None,
        "pressed_cell_frames": int(n_pressed.sum()), "contact_share": float(contact.mean()),
        "grip_cells": float(np.median(n_pressed[contact])) if contact.any() else None,
        "grip_shift": float(np.percentile(mean, 95) - np.median(mean[rest_frames])) if contact.any() else None,
        "depths": depths, "ranges": _ptp(raw),
        **{f"depth_{k}": (float(np.percentile(depths, q)) if depths.size else None)
           for k, q in (("p50", 50), ("p90", 90), ("max", 100))},
        "moving_live": int((live & (_ptp(raw) > MOVING)).sum()),
        "near": int(near.sum()), "below": int(below.sum()),
        "crosstalk_cells": int(xcol.sum()),
        "crosstalk_moving": int((_ptp(x) > MOVING).sum()) if x.size else 0,
        "crosstalk_rises": bool(x.size and ((x - x_rest).max(axis=0) >= PRESSED).any()),
        "crosstalk_falls": bool(x.size and ((x - x_rest).min(axis=0) <= -FALL).any()),
        "mid_grasp": bool(T >= START_FRAMES and n_pressed[:START_FRAMES].mean() >= MID_GRASP
                          and n_pressed[:START_FRAMES].mean() >= min(windows) + MID_GRASP_GAIN),
        "held": bool(contact.mean() >= HELD_SHARE),
        "max": float(raw.max()), "saturated_cells": int((raw.max(axis=0) >= 1015).sum()),
        "fine_step": float(np.diff(values).min()) if len(values) > 1 else None,
    }


def moving_bbox(ranges: list[np.ndarray]) -> tuple[int, int]:
    """(rows, cols) of the bounding box of the largest 4-connected group of cells moving (> MOVING) in any clip."""
    moving = np.any(np.stack([r > MOVING for r in ranges]), axis=0)
    lab, n = label(moving)
    if not n:
        return (0, 0)
    biggest = 1 + int(np.argmax(np.bincount(lab.ravel())[1:]))
    rr, cc = np.nonzero(lab == biggest)
    return int(rr.max() - rr.min() + 1), int(cc.max() - cc.min() + 1)


def _pct(values: list, q: float) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.percentile(values, q)) if values else None


def corpus_facts(rows: list[dict]) -> dict:
    """Pool per-(clip, hand) rows (each with "clip", "hand" added to `hand_facts`) into the numbers FACTS ranges."""
    working = [r for r in _select(rows, "working") if r["grip_cells"] is not None]
    support = [r for r in _select(rows, "support") if r["grip_cells"] is not None]
    depths = np.concatenate([r["depths"] for r in rows]) if rows else np.zeros(0)
    xcells = sum(r["crosstalk_cells"] for r in working)
    out = {
        "clip_hands": len(rows), "frames_min": min(r["frames"] for r in rows), "frames_max": max(r["frames"] for r in rows),
        "rest_left": _pct([r["rest"] for r in rows if r["hand"] == "left"], 50),
        "rest_right": _pct([r["rest"] for r in rows if r["hand"] == "right"], 50),
        "offset_p5_p95_p50": _pct([r["offset_p5_p95"] for r in rows], 50),
        "offset_range_p50": _pct([r["offset_range"] for r in rows], 50),
        "fine_step": min((r["fine_step"] for r in rows if r["fine_step"]), default=None),
        "wander_p50": _pct([r["wander"] for r in rows], 50),
        "wander_window_p50": _pct([r["wander_window"] for r in rows], 50),
        "wander_window_p90": _pct([r["wander_window"] for r in rows], 90),
        "gap_wander_window_p50": _pct([r["gap_wander_window"] for r in rows], 50),
        "fast_step_p50": _pct([r["fast_step"] for r in rows], 50),
        "working_hands": len(working),
        "grip_cells_min": _pct([r["grip_cells"] for r in working], 0),
        "grip_cells_p50": _pct([r["grip_cells"] for r in working], 50),
        "grip_cells_max": _pct([r["grip_cells"] for r in working], 100),
        "support_cells_p50": _pct([r["grip_cells"] for r in support], 50),
        "moving_live_p50": _pct([r["moving_live"] for r in working], 50),
        "grip_shift_min": _pct([r["grip_shift"] for r in working], 0),
        "grip_shift_p50": _pct([r["grip_shift"] for r in working], 50),
        "grip_shift_max": _pct([r["grip_shift"] for r in working], 100),
        "depth_p50": float(np.median(depths)) if depths.size else None,
        "depth_p90": float(np.percentile(depths, 90)) if depths.size else None,
        "depth_max": float(depths.max()) if depths.size else None,
        "below_rest_share": sum(r["below"] for r in rows) / max(sum(r["near"] for r in rows), 1),
        "crosstalk_moving_share": sum(r["crosstalk_moving"] for r in working) / xcells if xcells else None,
        "crosstalk_falls": float(any(r["crosstalk_falls"] for r in rows)),
        "mid_grasp_clips": float(sum(r["mid_grasp"] for r in rows)),
        "held_clips": float(sum(r["held"] for r in working)),
        "saturation": max(r["max"] for r in rows),
        "saturated_cells_p50": _pct([r["saturated_cells"] for r in rows], 50),
        "moving_box": float(max(np.prod(moving_bbox([r["ranges"] for r in rows if r["hand"] == h]))
                                for h in sorted({r["hand"] for r in rows}))),
    }
    return out


def fact_failures(pooled: dict) -> list[str]:
    """One line per FACTS range the pooled numbers fall outside (or cannot be measured)."""
    bad = []
    for f in FACTS:
        v = pooled.get(f.key)
        if v is None or not f.low <= v <= f.high:
            bad.append(f"{f.key} = {v!r}, outside [{f.low:g}, {f.high:g}]: {f.says}")
    return bad


def clip_rows(clip: str, counts: dict[str, np.ndarray], live: dict[str, np.ndarray]) -> list[dict]:
    """`hand_facts` of each hand of one clip, tagged with the clip and the hand."""
    return [{**hand_facts(raw, live[hand]), "clip": clip, "hand": hand} for hand, raw in counts.items()]


def npz_rows(paths: list, live: dict[str, np.ndarray], key: str = "counts",
             hands: tuple[str, ...] = ("left", "right")) -> list[dict]:
    """Rows of clips stored as npz files whose `key` holds (T, hands, H, W) raw counts (hand order `hands`)."""
    rows = []
    for path in paths:
        with np.load(path) as z:
            counts = z[key]
        rows += clip_rows(str(path), {h: counts[:, i] for i, h in enumerate(hands)}, live)
    return rows


def folder_rows(folder) -> list[dict]:
    """Rows of a folder of two-hand clips: FOLDER/clips/*.npz (key "counts", (T, 2, H, W), hand 0 = left) and
    FOLDER/layouts/*.json (one layout per hand, by its "hand"). The caller names the folder; nothing here looks
    for one."""
    folder = Path(folder)
    live = {}
    for path in sorted((folder / "layouts").glob("*.json")):
        layout = parse_layout(json.loads(path.read_text()), str(path))
        live[layout.hand] = np.asarray(layout.live_mask, bool)
    if set(live) != {"left", "right"}:
        raise ValueError(f"{folder / 'layouts'}: wants one layout per hand (left, right), found {sorted(live)}")
    paths = sorted((folder / "clips").glob("*.npz"))
    if not paths:
        raise ValueError(f"{folder / 'clips'}: no .npz clips")
    return npz_rows(paths, live)


def sample_rows(seed: int = 0) -> tuple[list[dict], list[dict]]:
    """(rows, truth) of the sample raw-count glove's corpus (`htdata sample --raw-glove`): the measures, and per
    working hand how well "pressed" measured from the counts alone matches the generator's truth."""
    _, clips = corpus_clips(seed)
    live = {h: glove_layout(h).live_mask for h in ("left", "right")}
    rows, truth = [], []
    for clip in clips:
        rows += clip_rows(clip.name, clip.counts, live)
        raw = clip.counts[clip.working].astype(np.float32)
        measured = ((raw - np.percentile(raw, 10, axis=0)) > PRESSED)[:, live[clip.working]]
        true = clip.truth_contact(clip.working)
        hit = int((measured & true).sum())
        truth.append({"clip": clip.name, "precision": hit / max(int(measured.sum()), 1),
                      "recall": hit / max(int(true.sum()), 1)})
    return rows, truth


# Measures compared number for number (`comparison`): key in the rows, which rows, what it says.
COMPARED = (
    ("rest", "all", "rest level (counts; per hand below)"),
    ("offset_p5_p95", "all", "per-cell offset spread, p5-p95 (counts)"),
    ("offset_range", "all", "per-cell offset spread, max - min (counts)"),
    ("wander_window", "all", "resting cell's range over 300 frames (counts, median)"),
    ("gap_wander_window", "all", "gap cell's range over 300 frames (counts, median)"),
    ("fast_step", "all", "resting cell's frame-to-frame step (counts, median)"),
    ("grip_cells", "working", "pressed cells per contact frame, working hand (median)"),
    ("grip_cells", "support", "pressed cells per contact frame, other hand (median)"),
    ("grip_shift", "working", "mean-level shift of a grip, working hand (counts)"),
    ("depth_p50", "working", "press depth of a pressed cell, median, working hand (counts)"),
    ("depth_p90", "working", "press depth, p90, working hand (counts)"),
    ("depth_max", "working", "press depth, deepest, working hand (counts)"),
    ("contact_share", "working", "share of frames in contact, working hand"),
    ("moving_live", "working", "live cells ranging > 20 counts in a clip, working hand"),
    ("crosstalk_moving", "working", "cross-talk column cells ranging > 20 counts, working hand"),
    ("below_share", "all", "share of a press's neighbours falling >= 10 below rest"),
    ("saturated_cells", "all", "cells reaching >= 1015 counts"),
)


def _select(rows: list[dict], which: str) -> list[dict]:
    by_clip: dict[str, list[dict]] = {}
    for r in rows:
        by_clip.setdefault(r["clip"], []).append(r)
    working = [max(rs, key=lambda r: r["pressed_cell_frames"]) for rs in by_clip.values()]
    if which == "working":
        return working
    if which == "support":
        return [r for r in rows if not any(r is w for w in working)]
    return rows


def spread(rows: list[dict], key: str, which: str) -> tuple[float, float, float] | None:
    """(min, median, max) of one measure over the (clip, hand) rows `which` selects ("all", "working", "support")."""
    chosen = _select(rows, which)
    if key == "below_share":
        values = [r["below"] / r["near"] for r in chosen if r["near"] and r["grip_cells"] is not None]
    else:
        values = [r[key] for r in chosen if r.get(key) is not None]
    if not values:
        return None
    return float(np.min(values)), float(np.median(values)), float(np.max(values))


def comparison(real: list[dict], sample: list[dict]) -> list[dict]:
    """One row per COMPARED measure (the rest level per hand): real and sample (min, median, max) over their
    (clip, hand) rows."""
    out = []
    for hand in ("left", "right"):
        out.append({"measure": f"rest level, {hand} hand (counts)",
                    "real": spread([r for r in real if r["hand"] == hand], "rest", "all"),
                    "sample": spread([r for r in sample if r["hand"] == hand], "rest", "all")})
    for key, which, says in COMPARED[1:]:
        out.append({"measure": says, "real": spread(real, key, which), "sample": spread(sample, key, which)})
    return out
