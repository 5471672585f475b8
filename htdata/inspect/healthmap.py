"""The taxel health map: two panels per glove (layout, hand), drawn with cv2.

Canonical panel: each live taxel's footprint (the pixels its value is
rendered to) is filled with the colour of the fault class it was given most
often over the assessed episodes (`CLASS_COLOURS`); a taxel never flagged is
"unexercised" (its own colour) when no episode ever exercised it, green
("healthy") otherwise; the canonical place outlines are drawn on top. Left
gloves are drawn mirrored into the right-hand frame, as the maps are.
Raw-grid panel: the glove's raw grid as recorded, one square per cell:
live taxels in their class colour, cells outside every block "unmapped"
(dark) or "unmapped, moving" (their own colour) when they moved in any
episode (raw-row health only), layout dead cells black.
The legend names each colour with the threshold that defines it, in glove
units when the health came from the raw rows (htdata/glove/rawhealth.py).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from htdata.errors import ArgumentError
from htdata.format.canvas import CANVAS
from htdata.glove import health, rawhealth
from htdata.glove.health import CLASSES
from htdata.inspect.episodestats import Glove
from htdata.inspect.outline import region_outline

PAD = 8
TITLE_H = 24
LEGEND_LINE = 15
BACKGROUND = (32, 32, 32)                 # BGR
HAND_GREY = (70, 70, 70)
HEALTHY = (80, 180, 80)
UNEXERCISED = (140, 110, 60)              # dull blue: never pressed, not a fault
UNMAPPED = (45, 45, 45)
UNMAPPED_MOVING = (0, 255, 180)           # yellow-green: a live cell the layout does not place
LAYOUT_DEAD = (0, 0, 0)
CLASS_COLOURS = {"saturated": (255, 255, 255), "stuck": (0, 200, 255), "dead": (0, 0, 230),
                 "noisy": (255, 0, 255), "drifting": (0, 120, 255), "crosstalk": (255, 160, 0)}
FONT = cv2.FONT_HERSHEY_SIMPLEX


def taxel_classes(per_episode: list[dict], layout_id: str, hand: str, glove: Glove) -> np.ndarray:
    """(L,) index into CLASSES of each live taxel's most frequent class, -1 = never flagged,
    UNEXERCISED_INDEX = never flagged and unexercised in every assessed episode."""
    pos = {tuple(c): i for i, c in enumerate(glove.taxels.cells.tolist())}
    counts = np.zeros((len(pos), len(CLASSES)), np.int64)
    idle = np.zeros(len(pos), np.int64)
    assessed = 0
    for h in _healths(per_episode, layout_id, hand):
        assessed += 1
        for k, name in enumerate(CLASSES):
            for cell in h["cells"].get(name, []):
                counts[pos[tuple(cell)], k] += 1
        for cell in h.get("unexercised_cells", []):
            idle[pos[tuple(cell)]] += 1
    out = np.where(counts.sum(axis=1) > 0, counts.argmax(axis=1), -1)
    out[(out < 0) & (idle == assessed) & (assessed > 0)] = UNEXERCISED_INDEX
    return out


UNEXERCISED_INDEX = -2


def _healths(per_episode: list[dict], layout_id: str, hand: str):
    for st in per_episode:
        h = st["hands"].get(hand)
        if h is not None and h["layout"] == layout_id and h["health"].get("assessed"):
            yield h["health"]


def _colour(k: int) -> tuple:
    return UNEXERCISED if k == UNEXERCISED_INDEX else HEALTHY if k < 0 else CLASS_COLOURS[CLASSES[k]]


def draw_grid_panel(glove: Glove, classes: np.ndarray, moving: set) -> np.ndarray:
    """The raw grid, one square per cell: live taxels by class, unmapped (moving) cells, layout dead cells."""
    layout = glove.layout
    H, W = layout.grid
    cell = max(1, (CANVAS - 8) // max(H, W))
    panel = np.empty((CANVAS, CANVAS, 3), np.uint8)
    panel[:] = BACKGROUND
    inside = np.zeros((H, W), bool)
    for b in layout.blocks:
        inside[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = True
    colours = {tuple(c): _colour(int(k)) for c, k in zip(glove.taxels.cells.tolist(), classes)}
    x0, y0 = (CANVAS - cell * W) // 2, (CANVAS - cell * H) // 2
    for r in range(H):
        for c in range(W):
            colour = colours.get((r, c))
            if colour is None:
                colour = (UNMAPPED_MOVING if (r, c) in moving else UNMAPPED) if not inside[r, c] else LAYOUT_DEAD
            y, x = y0 + r * cell, x0 + c * cell
            panel[y + 1:y + cell, x + 1:x + cell] = colour
    return panel


def draw_panel(glove: Glove, classes: np.ndarray, outline: np.ndarray) -> np.ndarray:
    panel = np.empty((CANVAS, CANVAS, 3), np.uint8)
    panel[:] = BACKGROUND
    panel[glove.canonical.region_map > 0] = HAND_GREY
    flat = panel.reshape(-1, 3)
    m = glove.rasteriser.matrix
    for k, cell in enumerate(glove.rasteriser.live_index):
        pix = m.indices[m.indptr[cell]:m.indptr[cell + 1]]
        flat[pix] = _colour(int(classes[k]))
    panel[outline] = (255, 255, 255)
    return panel


def render_health_map(per_episode: list[dict], gloves: dict[str, Glove], pairs: list[tuple[str, str]]
                      ) -> np.ndarray:
    """BGR image: a canonical and a raw-grid panel per (layout_id, hand) in `pairs`, a legend underneath."""
    if not pairs:
        raise ArgumentError("no glove with tactile frames: nothing to draw")
    bases = {b for lid, hand in pairs for h in _healths(per_episode, lid, hand) for b in [h.get("basis", "maps")]}
    healths = [h for lid, hand in pairs for h in _healths(per_episode, lid, hand) if h.get("basis") == "raw"]
    legend = _legend(bases, drift_told=any(h.get("drift_assessed") for h in healths) or not healths)
    width = PAD + len(pairs) * 2 * (CANVAS + PAD)
    img = np.empty((TITLE_H + CANVAS + PAD + LEGEND_LINE * len(legend) + PAD, max(width, 720), 3), np.uint8)
    img[:] = BACKGROUND
    for i, (layout_id, hand) in enumerate(pairs):
        glove = gloves[layout_id]
        x = PAD + 2 * i * (CANVAS + PAD)
        classes = taxel_classes(per_episode, layout_id, hand, glove)
        moving = {tuple(c) for h in _healths(per_episode, layout_id, hand) for c in h.get("unmapped_moving_cells", [])}
        img[TITLE_H:TITLE_H + CANVAS, x:x + CANVAS] = draw_panel(glove, classes,
                                                                 region_outline(glove.canonical.region_map))
        img[TITLE_H:TITLE_H + CANVAS, x + CANVAS + PAD:x + 2 * CANVAS + PAD] = draw_grid_panel(glove, classes, moving)
        cv2.putText(img, f"{hand}: {layout_id}"[:34], (x, 16), FONT, 0.4, (235, 235, 235), 1, cv2.LINE_AA)
        cv2.putText(img, "raw grid", (x + CANVAS + PAD, 16), FONT, 0.4, (235, 235, 235), 1, cv2.LINE_AA)
    y = TITLE_H + CANVAS + PAD + 11
    for colour, text in legend:
        cv2.rectangle(img, (PAD, y - 10), (PAD + 12, y + 2), colour, cv2.FILLED)
        cv2.putText(img, text, (PAD + 18, y), FONT, 0.38, (235, 235, 235), 1, cv2.LINE_AA)
        y += LEGEND_LINE
    return img


def _legend(bases: set, drift_told: bool = True) -> list[tuple[tuple, str]]:
    """(colour, "class: threshold") lines; thresholds in glove units when the health came from raw rows.
    `drift_told` False: no raw-row episode was long enough to tell drift, and the drifting line says so."""

    raw = "raw" in bases
    table = rawhealth.THRESHOLDS if raw else health.THRESHOLDS
    unit = "from the raw rows, shares of full scale" if raw else "from normalised values"
    lines = [(HEALTHY, f"healthy: none of the below ({unit}{'; some gloves from maps' if len(bases) > 1 else ''})")]
    lines += [(CLASS_COLOURS[c], f"{c}: {table[c]}") for c in CLASSES]
    if raw and not drift_told:
        k = 1 + CLASSES.index("drifting")
        lines[k] = (lines[k][0], f"drifting: NOT ASSESSED, every clip is shorter than "
                                 f"{rawhealth.DRIFT_MIN_FRAMES} frames (too short to tell drift from wander)")
    lines += [(UNEXERCISED, f"unexercised (not a fault): {table['unexercised']}")]
    lines += [(HAND_GREY, "no sensor: canonical hand outside the glove's coverage")]
    if raw:
        lines += [(UNMAPPED_MOVING, f"unmapped, moving (raw grid): {table['unmapped']}"),
                  (UNMAPPED, "unmapped (raw grid): outside every block, quiet"), (LAYOUT_DEAD, "layout dead cell")]
    return lines


def write_health_map(out, per_episode: list[dict], gloves: dict[str, Glove], pairs: list[tuple[str, str]]) -> Path:
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ArgumentError(f"{out}: the health map is written as PNG; give a .png path")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), render_health_map(per_episode, gloves, pairs)):
        raise OSError(f"{out}: cv2 could not write the PNG")
    return out
