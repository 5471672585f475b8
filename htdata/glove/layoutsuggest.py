"""A starting layout from recordings: blocks around the cells that move (`htdata layouts suggest`).

The glove's direction is read first (htdata.glove.activity.seen_direction: read
the wrong way, every press "only falls" below its rest like cross-talk) and
written as value.convention; when the recordings do not tell, "direct" is
written and the summary and the notes say it is a guess to check (or the
user states it: --convention). The cells are then read in the pressure
direction (an inverted glove's activity `mirrored`).
Per recording (each against its own noise and wander over the whole grid,
htdata.glove.activity's rule without the contact floor: a lightly pressed
taxel is still a sensor) the cells that move and do not only fall below
their rest (cross-talk) are counted: `support` = in how many recordings each
cell moved. Blocks are seeded on the cells that moved in at least
SUPPORT_MIN recordings when there are at least SUPPORT_FROM (a sensor area
is pressed again; a raw row shifting with one hard press, a cross-talk patch
or a short clip's noise is one recording's; when no area moved twice, in
one) and lie in a 2x2 square of such
cells (`sensor_areas`: a cross-talk line or a lone noisy cell is no sensor
area). The seed mask is cut into rectangles where it narrows and along rows
and columns that do not move (htdata.glove.blockcuts: on a real glove the
palm touches every finger strip and the thumb, so one bounding box would be
the whole grid), each block grows over neighbouring lines of cells that
moved in any recording (`grow_blocks`), and strips are cut into near-square
blocks, one per place (`split_strips`). The moving cells left outside every
block are counted in the summary and the layout's notes.
Blocks are given DISTINCT PLACEHOLDER places, largest block first: the
`palm` group when it fits (and no more than 15 blocks need places), then
the largest free place it fits (rotated by 90 when it only fits that way);
beyond the canonical hand's 18 places the smallest blocks are left out.
The places and orientations are guesses by
size, not anatomy: the user presses taxels, looks at `htdata layouts render`,
and edits each block's `place` and `rotate` / `flip_x` / `flip_y`
(docs/LAYOUTS.md). Cells inside a box that never moved stay live (they may
simply not have been pressed); every written layout parses.

`layout_json_text` is the compact JSON style of the shipped layout files
(one line per short list), shared with tools/derive_layouts.py.
"""

from __future__ import annotations

import json
import re

import numpy as np

from htdata.errors import ArgumentError
from htdata.glove.activity import CellActivity, SeenDirection, moving_cells, rule_text, seen_direction
from htdata.glove.blockcuts import cut_blocks, grow_blocks, join_lengthwise, split_strips
from htdata.glove.glovevalue import convention_name, is_inverted
from htdata.glove.layouts import load_canonical, parse_layout

SUPPORT_MIN = 2          # seed cells moved in at least this many recordings ...
SUPPORT_FROM = 3         # ... when at least this many are given (fewer: in one)


def layout_json_text(doc: dict) -> str:
    """Indented JSON with short number lists kept on one line (readable diffs)."""
    s = json.dumps(doc, indent=2)
    s = re.sub(r"\[\s+([-\d.,\s]+?)\s+\]",
               lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", s)
    # Cell lists: one [r, c] pair per entry, several per line.
    s = re.sub(r"\[\s+(\[\d+, \d+\](?:,\s+\[\d+, \d+\])*)\s+\]",
               lambda m: "[" + ", ".join(re.findall(r"\[\d+, \d+\]", m.group(1))) + "]", s)
    return s + "\n"


def layout_id_from_name(name: str) -> str:
    """A valid layout id from a file name ("My Glove-R.json" -> "my_glove_r")."""
    s = re.sub(r"[^a-z0-9_]+", "_", name.lower()).strip("_")
    return s if s and s[0].isalnum() else f"glove_{s}".strip("_")


def cell_boxes(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Inclusive (r0, r1, c0, c1) boxes around the 4-connected components of `mask`, merged until disjoint."""
    from scipy import ndimage

    labels, n = ndimage.label(mask)
    boxes = [(s[0].start, s[0].stop - 1, s[1].start, s[1].stop - 1) for s in ndimage.find_objects(labels)]
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] <= b[1] and b[0] <= a[1] and a[2] <= b[3] and b[2] <= a[3]:
                    boxes[i] = (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return sorted(boxes)


def sensor_areas(mask: np.ndarray) -> np.ndarray:
    """The moving cells that lie in some 2x2 square of moving cells: a sensor area is a patch, while a cross-talk
    line (one cell thick) or a lone noisy cell would join the blocks it touches into one box."""
    from scipy import ndimage

    return ndimage.binary_opening(np.asarray(mask, bool), structure=np.ones((2, 2), bool))


def _assign_places(boxes: list[tuple[int, int, int, int]]) -> list[tuple[str, int]]:
    """(place, rotate) per box: distinct targets, largest box first, each where it fits (the `palm` group for
    the largest when the others still find places: at most 1 + the 14 places outside the palm)."""
    canon = load_canonical()

    def size(t: str) -> tuple[int, int]:
        x0, y0, x1, y1 = canon.target_rect(t)
        return y1 - y0, x1 - x0

    places = sorted(canon.places, key=lambda p: -size(p)[0] * size(p)[1])
    palm_group = len(boxes) <= 1 + sum(not p.startswith("palm.") for p in places)
    taken: set[str] = set()
    out: dict[int, tuple[str, int]] = {}
    for i in sorted(range(len(boxes)), key=lambda i: -(boxes[i][1] - boxes[i][0] + 1) * (boxes[i][3] - boxes[i][2] + 1)):
        h, w = boxes[i][1] - boxes[i][0] + 1, boxes[i][3] - boxes[i][2] + 1
        free = (["palm"] if palm_group and not any(t.startswith("palm") for t in taken) else []) + \
               [p for p in places if p not in taken and not ("palm" in taken and p.startswith("palm."))]
        for target in free:
            ph, pw = size(target)
            if h <= ph and w <= pw:
                out[i] = (target, 0)
                break
            if w <= ph and h <= pw:
                out[i] = (target, 90)
                break
        else:
            raise ArgumentError(f"a block of {h}x{w} moving cells (rows {boxes[i][0]}-{boxes[i][1]}, cols "
                                f"{boxes[i][2]}-{boxes[i][3]}) fits no free place of the canonical hand; "
                                f"write that part of the layout by hand")
        taken.add(out[i][0])
    return [out[i] for i in range(len(boxes))]


UNSEEN_WIDTH = 3          # an uncovered region is at least this many lines across (thinner: the gap between strips)


def seed_support(recordings: int) -> int:
    """In how many recordings a cell must move to seed a block (module docstring)."""
    return SUPPORT_MIN if recordings >= SUPPORT_FROM else 1


def _largest_rectangle(mask: np.ndarray, least: int) -> tuple[int, int, int, int] | None:
    """(r0, r1, c0, c1) of the largest all-True rectangle of `mask` at least `least` cells both ways (row by row
    column heights, every rectangle under each histogram), None when there is none."""
    best, found = 0, None
    height = np.zeros(mask.shape[1], np.int64)
    for r, row in enumerate(mask):
        height = np.where(row, height + 1, 0)
        for c0 in range(len(height)):
            h = int(height[c0])
            for c1 in range(c0, len(height)):
                h = min(h, int(height[c1]))
                if h < least:
                    break
                if c1 - c0 + 1 >= least and h * (c1 - c0 + 1) > best:
                    best, found = h * (c1 - c0 + 1), (r - h + 1, r, c0, c1)
    return found


def uncovered_regions(boxes: list[tuple[int, int, int, int]], grid: tuple[int, int]) -> list[tuple[int, int, int, int]]:
    """Rectangles (r0, r1, c0, c1) inside the blocks' outline (their bounding box: the glove as far as the
    recordings show it) that no block covers: a finger strip or palm part the recordings did not press often
    enough to find, or no sensor at all (the user knows which). The largest first, each at least UNSEEN_WIDTH
    lines across both ways (narrower: the unsensed lines between strips), none overlapping a block."""
    left = np.zeros(grid, bool)
    left[min(b[0] for b in boxes):max(b[1] for b in boxes) + 1, min(b[2] for b in boxes):max(b[3] for b in boxes) + 1] = True
    for r0, r1, c0, c1 in boxes:
        left[r0:r1 + 1, c0:c1 + 1] = False
    out = []
    while (found := _largest_rectangle(left, UNSEEN_WIDTH)) is not None:
        r0, r1, c0, c1 = found
        out.append(found)
        left[r0:r1 + 1, c0:c1 + 1] = False
    return out


def unseen_text(regions: list[tuple[int, int, int, int]], places: list[str], least: int) -> str:
    """The summary's / notes' sentence on what the recordings did not show: the uncovered regions, and the places
    of a full canonical hand that got no block (`least`: recordings a block's cells must move in)."""
    canon = sorted(load_canonical().places)
    missing = [p for p in canon if p not in places and not (p.startswith("palm.") and "palm" in places)]
    where = "; ".join(f"rows {r0}-{r1}, cols {c0}-{c1}" for r0, r1, c0, c1 in regions)
    text = (f"no block covers {len(regions)} region(s) inside the blocks' outline: {where} (if one holds sensors, "
            f"record presses there: a block needs cells that move in {least} recording(s))" if regions
            else "the blocks cover their outline")
    if missing:
        text += (f"; {len(canon) - len(missing)} of the {len(canon)} places of a full hand have a block, none for "
                 f"{', '.join(missing)} (places by size: press every finger and the palm to find them all)")
    return text


def suggested_boxes(support: np.ndarray, recordings: int) -> list[tuple[int, int, int, int]]:
    """Block boxes from `support` (in how many of `recordings` each cell moved; module docstring), at most one
    per place of the canonical hand (the largest kept)."""
    seeds = cut_blocks(sensor_areas(support >= seed_support(recordings)))
    if not seeds:            # no area moved in two recordings: each was pressed once, so one is enough
        seeds = cut_blocks(sensor_areas(support >= 1))
    most = len(load_canonical().places)
    boxes = split_strips(join_lengthwise(grow_blocks(seeds, support >= 1, support)), most)
    if len(boxes) > most:
        boxes = sorted(sorted(boxes, key=lambda b: -(b[1] - b[0] + 1) * (b[3] - b[2] + 1))[:most])
    return boxes


def direction_note(convention: str, stated: bool, seen: SeenDirection) -> str:
    """The layout notes' / summary's sentence on value.convention: stated, seen, or a guess to check."""
    if stated:
        return f"value.convention {convention} as stated (--convention; the recordings: {seen.text()})"
    if seen.inverted is not None:
        return f"value.convention {convention} as the recordings show ({seen.text()})"
    return (f"value.convention {convention} is a GUESS, CHECK IT: the recordings do not show which way the counts "
            f"go with pressure ({seen.text()}); press one taxel, watch its raw count rise (direct) or fall "
            f"(inverted), and set it (or rerun with --convention)")


def suggest_layout(activities: list[CellActivity], hand: str, layout_id: str, integral: bool, sources: list[str],
                   max_value: float | None = None, convention: str | None = None) -> tuple[dict, dict]:
    """(layout document, summary) for the cells that move in any of `activities` (one per recording hand).

    Each recording is judged on its own (its own noise, its own range): a glove's rest level may differ
    between recordings, and pooling them would make that difference look like movement. The direction
    (value.convention) is `convention` when the user states it, else the one the recordings show
    (activity.seen_direction; "direct" when they do not tell, and the notes say so); the cells are read in
    the pressure direction, so an inverted glove gets the blocks a direct one would.
    """
    grid = activities[0].grid
    if any(a.grid != grid for a in activities):
        raise ArgumentError(f"recordings have different grids: {sorted({a.grid for a in activities})}")
    step = 1.0 if integral else None
    seen = seen_direction(activities, step)
    inverted = is_inverted(convention) if convention else bool(seen.inverted)
    direction = direction_note(convention_name(inverted), bool(convention), seen)
    support = np.zeros(grid, np.int64)
    noises, wanders, thresholds = [], [], []
    for a in (a.mirrored() if inverted else a for a in activities):
        found = moving_cells(a, np.ones(grid, bool), None, step)    # cross-talk (only falls) set apart
        support[found.cells[:, 0], found.cells[:, 1]] += 1
        noises.append(found.noise)
        wanders.append(found.wander)
        thresholds.append(found.threshold)
    noise, wander, threshold = float(np.median(noises)), float(np.median(wanders)), float(np.median(thresholds))
    frames = sum(a.frames for a in activities)
    mask = support > 0
    moving = int(mask.sum())     # every cell that rose in a recording; the blocks are drawn around sensor areas
    if not moving:
        raise ArgumentError(f"no cell moves in {', '.join(sources)} (noise {noise:.4g}, threshold "
                            f"{threshold:.4g} raw units over {frames} frames): press the glove while recording")
    boxes = suggested_boxes(support, len(activities))
    if not boxes:
        raise ArgumentError(f"the {moving} moving cell(s) in {', '.join(sources)} form no area of at least 2x2 cells "
                            f"(lines and single cells: cross-talk or noise, not a sensor area): press the glove "
                            f"while recording")
    inside = np.zeros(grid, bool)
    for r0, r1, c0, c1 in boxes:
        inside[r0:r1 + 1, c0:c1 + 1] = True
    lines = np.argwhere(mask & ~inside)
    targets = _assign_places(boxes)
    uncovered = uncovered_regions(boxes, grid)
    unseen = unseen_text(uncovered, [t for t, _ in targets], seed_support(len(activities)))
    top = float(max_value) if max_value is not None else max(float(a.hi[a.count > 0].max()) for a in activities)
    value = {"convention": convention_name(inverted), "max": int(top) if integral and top == int(top) else top}
    if integral:
        value["step"] = 1
    blocks = []
    for k, ((r0, r1, c0, c1), (place, rot)) in enumerate(zip(boxes, targets), start=1):
        b = {"name": f"block_{k}", "place": place, "rows": [int(r0), int(r1)], "cols": [int(c0), int(c1)],
             "flip_x": False, "flip_y": False}
        if rot:
            b["rotate"] = rot
        blocks.append(b)
    doc = {"layout_id": layout_id, "hand": hand, "grid": list(grid), "value": value, "blocks": blocks,
           "dead_cells": [], "bend_cells": [],
           "source": f"htdata layouts suggest from {', '.join(sources)} ({frames} frames)",
           "notes": (f"STARTING POINT, edit it: {moving} moving cells ({rule_text(full_scale=False)} in a recording; "
                     f"median noise {noise:.4g}, wander {wander:.4g}, threshold {threshold:.4g} raw units; cells that "
                     f"only fall below rest are cross-talk) cut into {len(blocks)} block(s); {len(lines)} moving "
                     f"cell(s) outside them (lines, lone cells, patches of one recording). Places were "
                     f"assigned by size, not anatomy: set each block's place and orientation (rotate, flip_x, "
                     f"flip_y; docs/LAYOUTS.md), split blocks that span several places, mark sensorless cells "
                     f"inside blocks as dead_cells and non-pressure cells as bend_cells, and set value.max to "
                     f"the glove's full-scale raw value (here: the largest value seen, {top:g}). {direction}. "
                     f"Not seen: {unseen}.")}
    parse_layout(doc, f"suggested layout {layout_id}")   # always a loadable starting point
    summary = {"moving": moving, "noise": noise, "wander": wander, "threshold": threshold, "frames": frames,
               "left_out": lines.tolist(),
               "recordings": len(activities), "convention": value["convention"], "direction": direction,
               "direction_unclear": not convention and seen.inverted is None,
               "uncovered": [list(map(int, b)) for b in uncovered], "unseen": unseen,
               "inside_blocks_not_moving": int((inside & ~mask).sum())}
    return doc, summary
