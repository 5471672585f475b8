"""Taxel health: classify every live taxel of one episode hand from its sampled value series.

Input is the (T, L) series of a glove's L live taxels over an episode's T
frames (normalised values: the stored maps sampled at the taxel centres, on
datasets without raw rows; where the raw rows are stored, htdata/glove/rawhealth.py
classifies the raw counts instead, in glove units), plus the layout geometry (`TaxelGrid`). Each
taxel gets at most one class, checked in this order:

- saturated: at the top of the scale (>= SATURATION_LEVEL) in more than
  SATURATED_SHARE of the frames;
- stuck: constant (p99 - p1 < NOISE_RANGE) at a level >= STUCK_LEVEL, away
  from the no-load value 0;
- dead: constant near 0 while the taxel was EXERCISED: in at least
  EXERCISED_FRAMES frames, at least DEAD_NEIGHBOURS of its same-block raw
  neighbours read >= PRESSED_LEVEL, two of them on opposite sides of it (a
  taxel just outside a sharp-edged press is not). A quiet taxel whose neighbourhood was
  never pressed is "unexercised", not dead: an idle finger is not a fault;
- noisy: its high-frequency level (75th percentile of the absolute second
  difference over time: smooth pressing and a few taps stay low, noise in
  most frames does not) above NOISY_MIN_HF and more than NOISY_RATIO times
  the median of its neighbours';
- cross-talk: in at least CROSSTALK_MIN_FRAMES frames (and in more than
  CROSSTALK_SHARE of the frames it is touched at all, > CROSSTALK_SIDE_LEVEL)
  it reads contact while nothing is touched within CROSSTALK_REACH raw rows
  (for a row line) or columns (for a column line) on either side of it
  (live taxels next to it on both sides, at least CROSSTALK_SIDE_TAXELS),
  and CROSSTALK_LINE_MATES other taxels of the same raw row / column do the
  same: a line lighting up without pressure around it is the ghosting of a
  resistive matrix. A press along the edge of a knit finger strip (4 raw
  lines wide) lights the edge line above contact while the strip's next
  lines are pressed more lightly, and passes contact in only some of the
  frames it is pressed (issue 43): the reach, the lighter side level and the
  touched frames keep it out. On the real glove's 12 dev clips (`htdata stats`
  taxel-episodes, left / right) the rule flagged 54 / 301, 0.61 / 0.39 of them
  true cross-talk (nothing pressed within the strip beside the line); now 2 / 4,
  all true (htdata/benchmarks/realglovecells.py `crosstalk_rows`). A ghost line running through real contact cannot be told from it
  and is not flagged.

Episodes shorter than MIN_FRAMES are not assessed (every taxel of a
one-frame episode is "constant"). Thresholds are module constants so a
report can quote them; `HEALTH_VERSION` changes when any of them does (it
is part of the stats cache key).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from htdata.glove.layouts import Layout

HEALTH_VERSION = 3            # 2: "drifting"; raw-row health (htdata/glove/rawhealth.py) where raw rows are stored;
                              # 3: cross-talk needs CROSSTALK_REACH untouched lines beside it (a strip-edge press)
CLASSES = ("saturated", "stuck", "dead", "noisy", "drifting", "crosstalk")
RECORD_HEALTH_VERSION = 1     # episode records' taxel_health (`record_entry`)
RECORD_CLASSES = ("saturated", "stuck", "dead", "noisy", "crosstalk")
MIN_FRAMES = 30
CONTACT_LEVEL = 0.02          # a taxel reads contact above this (validate's contact threshold)
NOISE_RANGE = 0.01            # p99 - p1 below this: no variation beyond noise
STUCK_LEVEL = 0.05            # a constant taxel at or above this is stuck, below it is dead / idle
SATURATION_LEVEL = 0.999      # half precision stores 1.0 exactly; 0.999 leaves round-off room
SATURATED_SHARE = 0.5
PRESSED_LEVEL = 0.1           # a neighbour "pressed" for the dead test
DEAD_NEIGHBOURS = 3           # (or all neighbours, if fewer)
EXERCISED_FRAMES = 3
NOISY_RATIO = 4.0
NOISY_MIN_HF = 0.05
CROSSTALK_MIN_FRAMES = 5
CROSSTALK_SHARE = 0.5
CROSSTALK_LINE_MATES = 2
CROSSTALK_SIDE_TAXELS = 3     # live taxels beside the line needed to call a reading isolated
CROSSTALK_REACH = 3           # lines on each side that must be untouched: a knit finger strip is 4 raw lines
                              # wide, and a press along its edge line leaves the strip's next lines touched
CROSSTALK_SIDE_LEVEL = CONTACT_LEVEL / 2    # "touched" beside the line: a light press there is still a press
THRESHOLDS = {"saturated": f">= {SATURATION_LEVEL} in > {SATURATED_SHARE:.0%} of frames",
              "stuck": f"constant (p99-p1 < {NOISE_RANGE}) at >= {STUCK_LEVEL}",
              "dead": f"constant below {STUCK_LEVEL} while neighbours read >= {PRESSED_LEVEL}",
              "noisy": f"high-frequency level > {NOISY_MIN_HF} and {NOISY_RATIO:g}x its neighbours'",
              "drifting": "needs the raw rows",
              "crosstalk": f"a raw row/column reads > {CONTACT_LEVEL} with nothing > {CROSSTALK_SIDE_LEVEL:g} within "
                           f"{CROSSTALK_REACH} lines beside it",
              "unexercised": f"constant below {STUCK_LEVEL}, neighbours never pressed",
              "unmapped": "needs the raw rows"}
# `htdata validate` warns when the flagged share of an episode hand's live taxels passes this.
WARN_SHARE = 0.05


_TAXEL_GRIDS: dict[int, tuple] = {}     # id(layout) -> (layout, TaxelGrid); layouts are few and cached too


@dataclass(frozen=True)
class TaxelGrid:
    """Where a layout's live taxels sit in its raw grid, and which are neighbours."""
    grid: tuple[int, int]
    cells: np.ndarray        # (L, 2) raw (row, col) of each live taxel, row-major order
    block: np.ndarray        # (L,) block index of each live taxel
    neighbours: list         # per taxel: indices of live 8-neighbours in the same block

    @classmethod
    def of(cls, layout: Layout) -> "TaxelGrid":
        """The layout's taxel grid, built once per Layout object: every episode of a glove shares it."""
        key = id(layout)
        if key not in _TAXEL_GRIDS:   # the layout is kept in the value, so its id is never reused
            _TAXEL_GRIDS[key] = (layout, cls._build(layout))
        return _TAXEL_GRIDS[key][1]

    @classmethod
    def _build(cls, layout: Layout) -> "TaxelGrid":
        H, W = layout.grid
        owner = np.full((H, W), -1, np.int64)
        for i, b in enumerate(layout.blocks):
            owner[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = i
        cells = np.argwhere(layout.live_mask)
        pos = np.full((H, W), -1, np.int64)
        pos[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
        neighbours = []
        for r, c in cells:
            near = []
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if (dr or dc) and 0 <= rr < H and 0 <= cc < W and pos[rr, cc] >= 0 \
                            and owner[rr, cc] == owner[r, c]:
                        near.append(int(pos[rr, cc]))
            neighbours.append(np.asarray(near, np.int64))
        return cls(grid=(H, W), cells=cells, block=owner[cells[:, 0], cells[:, 1]], neighbours=neighbours)


def classify(series: np.ndarray, taxels: TaxelGrid) -> dict:
    """(T, L) series -> {"assessed", "frames", "live", "counts" {class: n}, "cells" {class: [[r, c], ...]},
    "unexercised"} (cells in raw grid coordinates)."""
    x = np.asarray(series, np.float32)
    T, L = x.shape
    out = {"assessed": T >= MIN_FRAMES, "frames": int(T), "live": int(L), "basis": "maps",
           "counts": {c: 0 for c in CLASSES}, "cells": {c: [] for c in CLASSES}, "unexercised": 0,
           "unexercised_cells": []}
    if not out["assessed"] or L == 0:
        return out
    label = np.full(L, -1, np.int64)
    p1, p50, p99 = np.percentile(x, [1, 50, 99], axis=0)
    flat = (p99 - p1) < NOISE_RANGE
    saturated = (x >= SATURATION_LEVEL).mean(axis=0) > SATURATED_SHARE
    stuck = flat & (p50 >= STUCK_LEVEL) & (p50 < SATURATION_LEVEL)
    crosstalk = _crosstalk(x, taxels)
    exercised = _exercised(x, taxels, ignore=crosstalk)     # a ghost line presses nothing
    quiet = flat & (p50 < STUCK_LEVEL)
    out["unexercised"] = int((quiet & ~exercised).sum())
    # 75th percentile of |second difference|: smooth pressing and a few steps (taps) stay low, noise does not
    hf = np.percentile(np.abs(np.diff(x, n=2, axis=0)), 75, axis=0)
    near_hf = _neighbour_median(hf, taxels)
    noisy = (hf > NOISY_MIN_HF) & (hf > NOISY_RATIO * near_hf)
    masks = {"saturated": saturated, "stuck": stuck, "dead": quiet & exercised, "noisy": noisy,
             "crosstalk": crosstalk}         # drifting needs the raw rows (htdata/glove/rawhealth.py)
    for name, mask in masks.items():
        label[(label < 0) & mask] = CLASSES.index(name)
    out["unexercised_cells"] = taxels.cells[quiet & ~exercised & (label < 0)].tolist()
    for k, name in enumerate(CLASSES):
        hit = np.flatnonzero(label == k)
        out["counts"][name] = int(hit.size)
        out["cells"][name] = taxels.cells[hit].tolist()
    return out


def _neighbour_median(values: np.ndarray, taxels: TaxelGrid) -> np.ndarray:
    """(L,) median of each taxel's neighbours' non-NaN values (inf for a taxel without any).

    np.nanmedian's result, through the cached neighbour table and one sort (NaN sorts last): nanmedian
    goes through masked arrays, and this ran once per hand and episode.
    """
    near = _neighbour_tables(taxels)[0]
    table = np.append(np.asarray(values, np.float64), np.nan)[near]     # index -1 = no neighbour = NaN
    table.sort(axis=1)
    n = (~np.isnan(table)).sum(axis=1)
    rows = np.arange(len(table))
    # the middle one (odd n) or the two middle ones (even n) of the n values sorted first in each row
    lo, hi = table[rows, np.maximum(n - 1, 0) // 2], table[rows, n // 2]
    return np.where(n > 0, (lo + hi) / 2, np.inf)


def _neighbour_tables(taxels: TaxelGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(near (L,8) neighbour index or -1, opposite pairs (L,4,2) index or -1, neighbour counts (L,)).

    Kept on the (frozen) TaxelGrid after the first call: a glove's tables serve all its episodes.
    """
    cached = taxels.__dict__.get("_tables")
    if cached is not None:
        return cached
    L = len(taxels.neighbours)
    near = np.full((L, 8), -1, np.int64)
    pairs = np.full((L, 4, 2), -1, np.int64)
    counts = np.zeros(L, np.int64)
    for i, nb in enumerate(taxels.neighbours):
        near[i, :len(nb)] = nb
        counts[i] = len(nb)
        at = {tuple(o): int(k) for k, o in zip(nb, (taxels.cells[nb] - taxels.cells[i]).tolist())}
        for p, o in enumerate(((-1, -1), (-1, 0), (-1, 1), (0, -1))):     # one of each opposite pair
            a, b = at.get(o), at.get((-o[0], -o[1]))
            if a is not None and b is not None:
                pairs[i, p] = (a, b)
    object.__setattr__(taxels, "_tables", (near, pairs, counts))
    return near, pairs, counts


# Frames per block of the per-frame tests below: they only sum over frames, so blocks give the same
# counts with memory bounded by the block, not by the episode's length.
BLOCK_FRAMES = 512


def _blocks(x: np.ndarray):
    return (x[i:i + BLOCK_FRAMES] for i in range(0, len(x), BLOCK_FRAMES))


def _exercised(x: np.ndarray, taxels: TaxelGrid, ignore: np.ndarray) -> np.ndarray:
    """(L,) bool: enough neighbours (not in `ignore`) were pressed in enough frames to expect a reading.

    Per frame and taxel: at least min(DEAD_NEIGHBOURS, its neighbour count) neighbours pressed, two of
    them on opposite sides; vectorised over frames and taxels through padded neighbour tables.
    """
    near, pairs, counts = _neighbour_tables(taxels)
    frames = np.zeros(len(counts), np.int64)
    for block in _blocks(x):
        pressed = (block >= PRESSED_LEVEL) & ~ignore
        padded = np.concatenate([pressed, np.zeros((len(block), 1), bool)], axis=1)   # index -1 = never pressed
        n_pressed = padded[:, near].sum(axis=2, dtype=np.int8)                         # (T, L), <= 8 neighbours
        around = (padded[:, pairs[:, :, 0]] & padded[:, pairs[:, :, 1]]).any(axis=2)
        frames += (around & (n_pressed >= np.minimum(DEAD_NEIGHBOURS, counts))).sum(axis=0)
    return (counts > 0) & (frames >= EXERCISED_FRAMES)


def _crosstalk(x: np.ndarray, taxels: TaxelGrid) -> np.ndarray:
    """(L,) bool: the taxel lights up with its raw row / column mates and nothing around the line."""
    L = len(taxels.cells)
    n_ghost, n_active = np.zeros((2, L), np.int64), np.zeros(L, np.int64)
    for block in _blocks(x):
        ghost, active = _crosstalk_counts(block, taxels)
        n_ghost += ghost
        n_active += active
    found = np.zeros(L, bool)
    for axis in (0, 1):
        found |= (n_ghost[axis] >= CROSSTALK_MIN_FRAMES) & (n_ghost[axis] > CROSSTALK_SHARE * np.maximum(n_active, 1))
    return found


def _watched(taxels: TaxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """Per line axis (0: rows, 1: columns), the cells (padded by CROSSTALK_REACH) whose two sides both have live
    taxels next to the line to be quiet ("no contact nearby" means nothing elsewhere); depends on the layout
    only, so kept on the grid."""
    cached = taxels.__dict__.get("_watched")
    if cached is not None:
        return cached
    H, W = taxels.grid
    pad = CROSSTALK_REACH
    live = np.zeros((H + 2 * pad, W + 2 * pad), bool)
    live[taxels.cells[:, 0] + pad, taxels.cells[:, 1] + pad] = True
    out = []
    for axis in (0, 1):
        sides_live = []
        for d in (-1, 1):
            n_live = np.zeros(live.shape, np.int64)
            for e in (-1, 0, 1):
                n_live += np.roll(live, (d, e) if axis == 0 else (e, d), axis=(0, 1))
            sides_live.append(n_live)
        out.append((np.minimum(*sides_live) >= 1) & (sides_live[0] + sides_live[1] >= CROSSTALK_SIDE_TAXELS))
    object.__setattr__(taxels, "_watched", tuple(out))
    return tuple(out)


def _touched_beside(touched: np.ndarray, axis: int) -> np.ndarray:
    """(T, H', W') bool: some cell within CROSSTALK_REACH lines on either side of a row (axis 0) / column
    (axis 1) line, one cell along it either way, is touched. The padding (CROSSTALK_REACH) stops wrap-around."""
    out = np.zeros_like(touched)
    for d in (*range(-CROSSTALK_REACH, 0), *range(1, CROSSTALK_REACH + 1)):
        for e in (-1, 0, 1):
            out |= np.roll(touched, (d, e) if axis == 0 else (e, d), axis=(1, 2))
    return out


def _crosstalk_counts(x: np.ndarray, taxels: TaxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """((2, L) frames each taxel was a ghost on a row / column line, (L,) frames it was touched) in `x`."""
    H, W = taxels.grid
    T, pad = x.shape[0], CROSSTALK_REACH
    r, c = taxels.cells[:, 0] + pad, taxels.cells[:, 1] + pad
    lit = np.zeros((T, H + 2 * pad, W + 2 * pad), bool)
    lit[:, r, c] = x > CONTACT_LEVEL
    touched = np.zeros_like(lit)
    touched[:, r, c] = x > CROSSTALK_SIDE_LEVEL
    n_ghost = np.zeros((2, len(r)), np.int64)
    for axis in (0, 1):                            # 0: row lines (look above/below), 1: column lines
        isolated = lit & ~_touched_beside(touched, axis) & _watched(taxels)[axis]
        line = isolated.sum(axis=2 if axis == 0 else 1, keepdims=True, dtype=np.int16)   # a line < 2**15 taxels
        ghost = isolated & (line - isolated >= CROSSTALK_LINE_MATES)
        n_ghost[axis] = ghost[:, r, c].sum(axis=0)
    # touched, not lit: a press that only now and then passes the contact level is still a press in its other
    # frames, and its few isolated peaks are no ghost line
    return n_ghost, touched[:, r, c].sum(axis=0)


def record_entry(chunks: list[np.ndarray], layout: Layout) -> dict:
    """An episode hand's `taxel_health` in its episode record, from its (T_i, L) live-value chunks.

    The ingest (htdata.ingest.tally) and `htdata renormalise` write it:
    version, assessed, live, counts per class, unexercised, and the raw-grid
    cells of each flagged class.
    """
    series = np.concatenate(chunks) if chunks else np.zeros((0, int(layout.live_mask.sum())), np.float32)
    result = classify(series, TaxelGrid.of(layout))
    # the record keeps its version-1 form (the normalised-values classes; no "drifting", which needs the raw
    # rows): an episode record's bytes do not change with HEALTH_VERSION. `htdata stats` (the health map,
    # validate's warning, the card) classifies the raw rows where they are stored: htdata/glove/rawhealth.py.
    out = {"version": RECORD_HEALTH_VERSION, "assessed": result["assessed"], "live": result["live"],
           "counts": {c: result["counts"][c] for c in RECORD_CLASSES}, "unexercised": result["unexercised"]}
    flagged = {c: cells for c, cells in result["cells"].items() if cells and c in RECORD_CLASSES}
    if flagged:
        out["cells"] = flagged
    return out


def merge_counts(into: dict, health: dict) -> None:
    """Add one episode hand's classification to a running summary (counts, taxels assessed)."""
    into.setdefault("episodes_assessed", 0)
    into.setdefault("episodes_not_assessed", 0)
    into.setdefault("taxels_assessed", 0)
    into.setdefault("unexercised", 0)
    into.setdefault("unmapped_moving", 0)
    into.setdefault("basis", [])
    counts = into.setdefault("counts", {c: 0 for c in CLASSES})
    if not health.get("assessed"):
        into["episodes_not_assessed"] += 1
        return
    into["episodes_assessed"] += 1
    if health.get("basis") == "raw":     # drift is told from raw rows only, on long enough episodes
        key = "drift_assessed" if health.get("drift_assessed") else "drift_not_assessed"
        into[key] = into.get(key, 0) + 1
    into["taxels_assessed"] += int(health["live"])
    into["unexercised"] += int(health.get("unexercised", 0))
    into["unmapped_moving"] += int(health.get("unmapped_moving", 0))
    if health.get("basis", "maps") not in into["basis"]:
        into["basis"].append(health.get("basis", "maps"))
    for c in CLASSES:
        counts[c] += int(health["counts"].get(c, 0))


def flagged_share(health: dict) -> float:
    """Share of an episode hand's live taxels with any fault class (0 when not assessed)."""
    if not health.get("assessed") or not health.get("live"):
        return 0.0
    return sum(health["counts"].values()) / health["live"]
