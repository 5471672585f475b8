"""Dev-time: derive the shipped glove layouts from the source releases' facts.

For a glove of your own, use `htdata layouts suggest RECORDING... OUT.json`
(a starting layout from the cells that move in recordings, written in the
same JSON style); this tool only holds the facts of the three shipped
layouts, read from the releases' reference files.

Reads the reference files given as --reference (the source releases' OpenTouch
taxel regions, TouchAnything NaN masks, bend-sensor positions and derived
regions, with the format notes that state their facts; they are not part of
this repository), cross-checks them against those facts, and writes
schemas/layouts/{opentouch_right_16x16,touchanything_left_21x21,
touchanything_right_21x21}.json. Runtime code never reads the reference
directory; it reads only the files written here.

    .venv/bin/python tools/derive_layouts.py --reference DIR [--check]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from htdata.glove.layouts import parse_layout  # noqa: E402
from htdata.glove.layoutsuggest import layout_json_text  # noqa: E402

OUT_DIR = ROOT / "schemas" / "layouts"

# OpenTouch region name -> canonical place (rows 0-2 distal ... 6-8 proximal;
# pa4/pa3 upper palm, pa1/pa2 lower palm; t1 = proximal thumb, t2 = distal).
OPENTOUCH_PLACES = {
    "p3": "little.distal", "p2": "little.middle", "p1": "little.proximal",
    "r3": "ring.distal", "r2": "ring.middle", "r1": "ring.proximal",
    "m3": "middle.distal", "m2": "middle.middle", "m1": "middle.proximal",
    "i3": "index.distal", "i2": "index.middle", "i1": "index.proximal",
    "pa4": "palm.upper_ulnar", "pa3": "palm.upper_radial",
    "pa1": "palm.lower_ulnar", "pa2": "palm.lower_radial",
    "t1": "thumb.proximal", "t2": "thumb.distal",
}

# TouchAnything LEFT grid as stored: block -> (place, rows, cols, regions_derived key).
TOUCHANYTHING_LEFT_BLOCKS = [
    ("little_tip", "little.distal", (2, 5), (1, 3), "little_tip_tactile"),
    ("ring_tip", "ring.distal", (2, 5), (5, 7), "ring_tip_tactile"),
    ("middle_tip", "middle.distal", (2, 5), (9, 11), "middle_tip_tactile"),
    ("index_tip", "index.distal", (2, 5), (13, 15), "index_tip_tactile"),
    ("thumb_tip", "thumb.distal", (6, 9), (17, 19), "thumb_tip_tactile"),
    ("palm", "palm", (13, 17), (1, 19), "palm_tactile"),
]


def dump_json(doc: dict, path: Path) -> None:
    """The shipped layout files' JSON style (htdata.glove.layoutsuggest.layout_json_text, shared with
    `htdata layouts suggest`)."""
    path.write_text(layout_json_text(doc))


def opentouch_layout(ref: Path) -> dict:
    d = json.loads((ref / "opentouch" / "right_taxel_regions.json").read_text())
    live = {tuple(int(v) for v in k.split("-")) for k in d["taxels"]}
    erased = {tuple(int(v) for v in k.split("-")) for k in d["erased"]}
    assert len(live) == 169 and len(erased) == 87 and not live & erased, "OpenTouch: 169 live + 87 erased"
    blocks, in_blocks = [], set()
    for name in OPENTOUCH_PLACES:
        reg = d["regions"][name]
        (r0, r1), (c0, c1) = reg["rows"], reg["cols"]
        cells = {(r, c) for r in range(r0, r1 + 1) for c in range(c0, c1 + 1)}
        assert all(d["taxels"][f"{r}-{c}"]["region"] == name for r, c in cells & live), name
        in_blocks |= cells
        # Columns already run little (0) -> thumb (15), as the canonical x axis does.
        blocks.append({"name": name, "place": OPENTOUCH_PLACES[name], "rows": [r0, r1], "cols": [c0, c1],
                       "flip_x": False, "flip_y": False})
    assert live <= in_blocks, "every OpenTouch taxel lies in a region block"
    dead = sorted(in_blocks - live)
    return {
        "layout_id": "opentouch_right_16x16",
        "hand": "right",
        "grid": [16, 16],
        "value": {"convention": "inverted", "max": 3072, "step": 1},
        "blocks": blocks,
        "dead_cells": [list(c) for c in dead],
        "bend_cells": [],
        "source": "OpenTouch release: right_pressure[T,16,16]; regions from WiReSensBackend "
                  "exampleAnalyze.ipynb (right_hand_regions), valid taxels = complement of erasedNodes in "
                  "OpenTouch preprocess handLayoutNewest_meshid.json (169 live of 256).",
        "notes": "Firmware 0..3072, 3072 = no load, 0 = saturated: contact = clip((3072 - p) / 3072, 0, 1). "
                 "Finger rows 0-2 distal, 3-5 middle, 6-8 proximal; raw columns run ulnar (little, col 0) "
                 "to radial (thumb, col 15) like the canonical x axis, so no block is flipped. The thumb's "
                 "long axis runs along the grid columns (t1 cols 11-12 proximal, t2 cols 13-15 distal); "
                 "blocks are resampled without rotation, so inside a thumb place x follows the raw columns.",
    }


def touchanything_left_layout(ref: Path) -> dict:
    ta = ref / "touchanything"
    nan_left = np.array(json.loads((ta / "nan_masks.json").read_text())["left"])
    valid = {tuple(map(int, rc)) for rc in np.argwhere(nan_left == 0)}
    joints = json.loads((ta / "hand_joint_positions.json").read_text())
    bend = sorted({(int(j["row"]), int(j["col"])) for j in joints["left"]})
    derived = json.loads((ta / "regions_derived.json").read_text())["left"]
    assert len(valid) == 217 and len(bend) == 66 and set(bend) <= valid, "TouchAnything: 217 valid, 66 bend"
    pressure = valid - set(bend)
    assert len(pressure) == 151
    blocks, in_blocks = [], set()
    for name, place, (r0, r1), (c0, c1), key in TOUCHANYTHING_LEFT_BLOCKS:
        cells = {(r, c) for r in range(r0, r1 + 1) for c in range(c0, c1 + 1)}
        assert {tuple(rc) for rc in derived[key]} == cells & pressure, name
        in_blocks |= cells
        blocks.append({"name": name, "place": place, "rows": [r0, r1], "cols": [c0, c1],
                       "flip_x": False, "flip_y": False})
    assert pressure <= in_blocks and not (set(bend) & in_blocks)
    dead = sorted(in_blocks - pressure)
    return {
        "layout_id": "touchanything_left_21x21",
        "hand": "left",
        "grid": [21, 21],
        "value": {"convention": "direct", "max": 1.0, "step": 1 / 255},
        "blocks": blocks,
        "dead_cells": [list(c) for c in dead],
        "bend_cells": [list(c) for c in bend],
        "source": "TouchAnything release configs (MIT): nan_masks (217 valid cells), hand_joint_positions.json "
                  "'left' (66 bend cells), pressure regions from the hand-mesh mapping (regions_derived).",
        "notes": "LEFT grid as stored: little tip cols 1-3 ... index tip cols 13-15, thumb tip cols 17-19, so "
                 "raw columns already run ulnar (little, low columns) to radial (thumb, high columns), the same "
                 "direction as the canonical right-hand palmar frame (thumb on the right): flip_x is false and "
                 "the left hand is mirrored into the right-hand frame simply by this column order. Only "
                 "fingertips and the palm carry pressure; the palm box rows 13-17 x cols 1-19 is drawn over "
                 "the whole palm group and its 4 sensorless cells (row 13, cols 16-19) are dead_cells. "
                 "Bend (flex) cells are stored apart and never drawn.",
    }


def mirror_layout(left: dict, width: int) -> dict:
    """The RIGHT grid is stored mirrored: stored col c = left col (width-1) - c."""
    m = width - 1
    blocks = [{**b, "cols": [m - b["cols"][1], m - b["cols"][0]], "flip_x": not b["flip_x"]} for b in left["blocks"]]
    return {
        "layout_id": left["layout_id"].replace("_left_", "_right_"),
        "hand": "right",
        "grid": list(left["grid"]),
        "value": dict(left["value"]),
        "blocks": blocks,
        "dead_cells": sorted([r, m - c] for r, c in left["dead_cells"]),
        # Same order as the left layout, so bend_vector index k is the same joint on both hands.
        "bend_cells": [[r, m - c] for r, c in left["bend_cells"]],
        "source": left["source"].replace("'left'", "'right'"),
        "notes": "RIGHT grid as stored is the left layout mirrored (stored col c = left col 20 - c): thumb tip "
                 "cols 1-3, little tip cols 17-19. Raw columns therefore run radial -> ulnar, so every block "
                 "has flip_x true; a right grid equal to the left grid with its columns reversed renders to the "
                 "same canonical map.",
    }


def check_right_against_reference(right: dict, ref: Path) -> None:
    ta = ref / "touchanything"
    nan_right = np.array(json.loads((ta / "nan_masks.json").read_text())["right"])
    joints = json.loads((ta / "hand_joint_positions.json").read_text())
    assert sorted([int(j["row"]), int(j["col"])] for j in joints["right"]) == sorted(right["bend_cells"])
    valid = {tuple(map(int, rc)) for rc in np.argwhere(nan_right == 0)}
    derived = json.loads((ta / "regions_derived.json").read_text())["right"]
    assert {tuple(rc) for rc in derived["thumb_tip_tactile"]} == {(r, c) for r in range(6, 10) for c in range(1, 4)}
    assert len(valid) == 217


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reference", type=Path, required=True,
                    help="folder of the source releases' reference files (not in this repository)")
    ap.add_argument("--check", action="store_true", help="only compare with the committed files")
    args = ap.parse_args(argv)
    ot = opentouch_layout(args.reference)
    left = touchanything_left_layout(args.reference)
    right = mirror_layout(left, left["grid"][1])
    check_right_against_reference(right, args.reference)
    status = 0
    for doc in (ot, left, right):
        path = OUT_DIR / f"{doc['layout_id']}.json"
        parse_layout(doc, str(path))  # schema + geometry validation before writing
        if args.check:
            same = path.is_file() and json.loads(path.read_text()) == doc
            print(f"{'ok  ' if same else 'DIFF'} {path}")
            status |= 0 if same else 1
        else:
            dump_json(doc, path)
            print(f"wrote {path}")
    return status


if __name__ == "__main__":
    sys.exit(main())
