"""The taxel health map: one panel per glove (layout, hand) in the canonical hand frame, drawn with cv2.

Each live taxel's footprint (the pixels its value is rendered to) is filled
with the colour of the fault class it was given most often over the
assessed episodes (`CLASS_COLOURS`), green when never flagged; the
canonical place outlines are drawn on top and a legend names the colours.
Left gloves are drawn mirrored into the right-hand frame, as the maps are.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from htdata.episodestats import Glove
from htdata.format import CANVAS
from htdata.health import CLASSES

PAD = 8
TITLE_H = 24
LEGEND_H = 26
BACKGROUND = (32, 32, 32)                 # BGR
HAND_GREY = (70, 70, 70)
HEALTHY = (80, 180, 80)
CLASS_COLOURS = {"saturated": (255, 255, 255), "stuck": (0, 200, 255), "dead": (0, 0, 230),
                 "noisy": (255, 0, 255), "crosstalk": (255, 160, 0)}
FONT = cv2.FONT_HERSHEY_SIMPLEX


def taxel_classes(per_episode: list[dict], layout_id: str, hand: str, glove: Glove) -> np.ndarray:
    """(L,) index into CLASSES of each live taxel's most frequent class, -1 = never flagged."""
    pos = {tuple(c): i for i, c in enumerate(glove.taxels.cells.tolist())}
    counts = np.zeros((len(pos), len(CLASSES)), np.int64)
    for st in per_episode:
        h = st["hands"].get(hand)
        if h is None or h["layout"] != layout_id or not h["health"].get("assessed"):
            continue
        for k, name in enumerate(CLASSES):
            for cell in h["health"]["cells"][name]:
                counts[pos[tuple(cell)], k] += 1
    return np.where(counts.sum(axis=1) > 0, counts.argmax(axis=1), -1)


def draw_panel(glove: Glove, classes: np.ndarray, outline: np.ndarray) -> np.ndarray:
    panel = np.empty((CANVAS, CANVAS, 3), np.uint8)
    panel[:] = BACKGROUND
    panel[glove.canonical.region_map > 0] = HAND_GREY
    flat = panel.reshape(-1, 3)
    m = glove.rasteriser.matrix
    for k, cell in enumerate(glove.rasteriser.live_index):
        pix = m.indices[m.indptr[cell]:m.indptr[cell + 1]]
        flat[pix] = CLASS_COLOURS[CLASSES[classes[k]]] if classes[k] >= 0 else HEALTHY
    panel[outline] = (255, 255, 255)
    return panel


def render_health_map(per_episode: list[dict], gloves: dict[str, Glove], pairs: list[tuple[str, str]]
                      ) -> np.ndarray:
    """BGR image: one panel per (layout_id, hand) in `pairs`, a legend underneath."""
    if not pairs:
        raise ValueError("no glove with tactile frames: nothing to draw")
    from htdata.preview import region_outline
    width = PAD + len(pairs) * (CANVAS + PAD)
    img = np.empty((TITLE_H + CANVAS + PAD + LEGEND_H, max(width, 520), 3), np.uint8)
    img[:] = BACKGROUND
    for i, (layout_id, hand) in enumerate(pairs):
        glove = gloves[layout_id]
        x = PAD + i * (CANVAS + PAD)
        panel = draw_panel(glove, taxel_classes(per_episode, layout_id, hand, glove),
                           region_outline(glove.canonical.region_map))
        img[TITLE_H:TITLE_H + CANVAS, x:x + CANVAS] = panel
        cv2.putText(img, f"{hand}: {layout_id}"[:34], (x, 16), FONT, 0.4, (235, 235, 235), 1, cv2.LINE_AA)
    x, y = PAD, TITLE_H + CANVAS + PAD + 16
    for name, colour in (("healthy", HEALTHY), *CLASS_COLOURS.items()):
        cv2.rectangle(img, (x, y - 10), (x + 12, y + 2), colour, cv2.FILLED)
        cv2.putText(img, name, (x + 16, y), FONT, 0.4, (235, 235, 235), 1, cv2.LINE_AA)
        x += 24 + cv2.getTextSize(name, FONT, 0.4, 1)[0][0]
    return img


def write_health_map(out, per_episode: list[dict], gloves: dict[str, Glove], pairs: list[tuple[str, str]]) -> Path:
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"{out}: the health map is written as PNG; give a .png path")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), render_health_map(per_episode, gloves, pairs)):
        raise OSError(f"{out}: cv2 could not write the PNG")
    return out
