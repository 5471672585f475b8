"""Where the sample raw-count glove's sensors sit on its 32x32 raw grid, and its layout files.

The wiring follows the two-hand 32x32 knitted gloves the sample glove copies
(issue 34): the sensor is ONE connected knit. The palm fills raw rows 0-22 x
columns 0-18; each finger is a 4-row strip along raw columns 19-30 (base at
column 19, tip at column 30: proximal, middle, distal segments of 4 columns)
whose base touches the palm's column 18; the thumb fills rows 23-31 x
columns 6-12 below the palm (tip at row 31). Rows between the finger strips
and the cells around the thumb carry no sensor; column 31 carries no sensor
and picks up cross-talk. So in the raw grid the palm touches every finger
strip and the thumb, and a box around connected moving cells is the whole
grid.

`layout_doc` writes it as a layout (fingers and palm `rotate` 270: raw
columns drawn vertically, tip up; thumb `flip_y`), every cell outside the
blocks listed in `unused_cells`.
"""

from __future__ import annotations

import numpy as np

from htdata.glove.layouts import parse_layout

GRID = (32, 32)
FULL_SCALE = 1023.0        # layout value.max: full-scale raw (10-bit ADC)
VALUE_STEP = 0.25          # float16 counts: 0.25-count steps below 512, 0.5 above
LAYOUT_IDS = {"left": "rawknit_left_32x32", "right": "rawknit_right_32x32"}

FINGER_ROWS = {"little": (0, 3), "ring": (6, 9), "middle": (11, 14), "index": (19, 22)}
SEGMENT_COLS = {"proximal": (19, 22), "middle": (23, 26), "distal": (27, 30)}
PALM = {"palm_lower_ulnar": ((0, 11), (0, 9)), "palm_upper_ulnar": ((0, 11), (10, 18)),
        "palm_lower_radial": ((12, 22), (0, 9)), "palm_upper_radial": ((12, 22), (10, 18))}
THUMB = {"thumb_proximal": ((23, 27), (6, 12)), "thumb_distal": ((28, 31), (6, 12))}
CROSSTALK_COL = 31         # no sensor: moves with the presses of its row (cross-talk)


def blocks() -> list[dict]:
    """The blocks of one hand (both hands are wired alike)."""
    out = []
    for finger, rows in FINGER_ROWS.items():
        for seg, cols in SEGMENT_COLS.items():
            out.append({"name": f"{finger}_{seg}", "place": f"{finger}.{seg}", "rows": list(rows),
                        "cols": list(cols), "rotate": 270})
    for name, (rows, cols) in PALM.items():
        out.append({"name": name, "place": name.replace("_", ".", 1), "rows": list(rows), "cols": list(cols),
                    "rotate": 270})
    for name, (rows, cols) in THUMB.items():
        out.append({"name": name, "place": name.replace("_", ".", 1), "rows": list(rows), "cols": list(cols),
                    "flip_y": True})
    return out


def sensor_mask() -> np.ndarray:
    """(32,32) bool: the cells inside a block."""
    inside = np.zeros(GRID, bool)
    for b in blocks():
        inside[b["rows"][0]:b["rows"][1] + 1, b["cols"][0]:b["cols"][1] + 1] = True
    return inside


def layout_doc(hand: str) -> dict:
    """The layout document of one hand of the raw-count glove."""
    # The cells outside the blocks are knit too and read counts (the cross-talk column among them): listed as
    # deliberately unused, so a moving cell outside the blocks is a finding, not the gaps' noise.
    unused = [[int(r), int(c)] for r, c in np.argwhere(~sensor_mask())]
    return {"layout_id": LAYOUT_IDS[hand], "hand": hand, "grid": list(GRID),
            "value": {"convention": "direct", "max": FULL_SCALE, "step": VALUE_STEP},
            "blocks": blocks(), "dead_cells": [], "bend_cells": [], "unused_cells": unused,
            "source": "htdata sample raw-count glove (htdata/synthetic/rawglove.py): synthetic",
            "notes": "float16 10-bit counts, rest ~557 (left) / ~566 (right) with per-cell offsets, full scale "
                     "1023. Fingers along raw columns (col 19 base, col 30 tip), 4-row strips: little rows 0-3, "
                     "ring 6-9, middle 11-14, index 19-22; palm rows 0-22 x cols 0-18; thumb rows 23-31 x cols "
                     "6-12 (row 31 tip); column 31 carries cross-talk."}


def glove_layout(hand: str):
    return parse_layout(layout_doc(hand), f"<{LAYOUT_IDS[hand]}>")
