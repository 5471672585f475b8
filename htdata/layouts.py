"""Canonical hand template and glove layouts, both plain JSON data.

`schemas/layouts/canonical_hand.json` places anatomical regions on a 224x224
right-hand palmar canvas; `schemas/layouts/<layout_id>.json` says which
rectangle ("block") of a glove's raw taxel grid lands on which place. A new
glove is registered by writing one such file (docs/LAYOUTS.md); this module
loads and validates both and exposes the `htdata layouts` command.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from htdata.resources import LAYOUTS_DIR, validate_json

CANVAS = 224
CANONICAL_FILE = "canonical_hand.json"
PART_NAMES: dict[int, str] = {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "little", 6: "palm"}
GROUPS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little", "palm")

Rect = tuple[int, int, int, int]


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------- canonical


@dataclass(frozen=True)
class CanonicalHand:
    """The 224x224 template: places, their region ids and the label maps."""

    places: dict[str, Rect]
    region_ids: dict[str, int]
    region_map: np.ndarray  # (224,224) uint8 region id, 0 = outside
    part_map: np.ndarray  # (224,224) uint8 part id, 0 = outside
    part_names: dict[int, str]
    part_of_region: dict[int, int]  # region id -> part id
    groups: dict[str, Rect]  # group name -> bounding box of its places
    source: dict = field(repr=False, default_factory=dict)

    def target_rect(self, target: str) -> Rect:
        """Rectangle a block is resampled over: a place's rect or a group's bbox."""
        if target in self.places:
            return self.places[target]
        if target in self.groups:
            return self.groups[target]
        raise KeyError(target)

    def target_mask(self, target: str) -> np.ndarray:
        """Pixels a block targeting `target` may draw on (only inside places)."""
        if target in self.places:
            return self.region_map == self.region_ids[target]
        if target in self.groups:
            return self.part_map == GROUPS.index(target) + 1
        raise KeyError(target)

    def to_dict(self) -> dict:
        return json.loads(json.dumps(self.source))


def _bbox(rects: list[Rect]) -> Rect:
    a = np.array(rects)
    return (int(a[:, 0].min()), int(a[:, 1].min()), int(a[:, 2].max()), int(a[:, 3].max()))


def _rects_overlap(a: Rect, b: Rect) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def parse_canonical(doc: dict, where: str = CANONICAL_FILE) -> CanonicalHand:
    """Validate a canonical template document and build its label maps."""
    validate_json(doc, "canonical_hand", where)
    places: dict[str, Rect] = {}
    region_ids: dict[str, int] = {}
    for name, spec in doc["places"].items():
        x0, y0, x1, y1 = (int(v) for v in spec["rect"])
        if not (0 <= x0 < x1 <= CANVAS and 0 <= y0 < y1 <= CANVAS):
            raise ValueError(f"{where}: place {name!r}: rect {spec['rect']} is empty or outside the canvas")
        places[name] = (x0, y0, x1, y1)
        region_ids[name] = int(spec["region_id"])
    if sorted(region_ids.values()) != list(range(1, len(places) + 1)):
        raise ValueError(f"{where}: region ids must be exactly 1..{len(places)}, got {sorted(region_ids.values())}")
    names = list(places)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if _rects_overlap(places[a], places[b]):
                raise ValueError(f"{where}: places {a!r} and {b!r} overlap")
    groups = {g: _bbox([r for n, r in places.items() if n.split(".")[0] == g]) for g in GROUPS}
    for g, box in groups.items():
        for n, r in places.items():
            if n.split(".")[0] != g and _rects_overlap(box, r):
                raise ValueError(f"{where}: bounding box of group {g!r} {box} overlaps place {n!r}")

    region_map = np.zeros((CANVAS, CANVAS), np.uint8)
    part_map = np.zeros((CANVAS, CANVAS), np.uint8)
    part_of_region: dict[int, int] = {}
    for name, (x0, y0, x1, y1) in places.items():
        part = GROUPS.index(name.split(".")[0]) + 1
        region_map[y0:y1, x0:x1] = region_ids[name]
        part_map[y0:y1, x0:x1] = part
        part_of_region[region_ids[name]] = part
    return CanonicalHand(places=places, region_ids=region_ids, region_map=_frozen(region_map),
                         part_map=_frozen(part_map), part_names=dict(PART_NAMES),
                         part_of_region=part_of_region, groups=groups, source=doc)


@lru_cache(maxsize=1)
def load_canonical() -> CanonicalHand:
    """The shipped template (`schemas/layouts/canonical_hand.json`), cached."""
    path = LAYOUTS_DIR / CANONICAL_FILE
    return parse_canonical(json.loads(path.read_text()), str(path))


# --------------------------------------------------------------------------- glove layouts


@dataclass(frozen=True)
class Block:
    """A rectangle of the raw grid (inclusive ranges) drawn onto one place or group."""

    name: str
    place: str
    rows: tuple[int, int]
    cols: tuple[int, int]
    flip_x: bool = False
    flip_y: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows[1] - self.rows[0] + 1, self.cols[1] - self.cols[0] + 1)

    def cell_rows(self, display_rows: np.ndarray) -> np.ndarray:
        """Raw row of a row counted from the top of the canvas rectangle."""
        return self.rows[1] - display_rows if self.flip_y else self.rows[0] + display_rows

    def cell_cols(self, display_cols: np.ndarray) -> np.ndarray:
        """Raw column of a column counted from the left of the canvas rectangle."""
        return self.cols[1] - display_cols if self.flip_x else self.cols[0] + display_cols

    def to_dict(self) -> dict:
        return {"name": self.name, "place": self.place, "rows": list(self.rows),
                "cols": list(self.cols), "flip_x": self.flip_x, "flip_y": self.flip_y}


@dataclass(frozen=True)
class Layout:
    """A validated glove layout."""

    layout_id: str
    hand: str
    grid: tuple[int, int]
    value: dict
    blocks: tuple[Block, ...]
    dead_cells: np.ndarray  # (D,2) int
    bend_cells: np.ndarray  # (K,2) int
    live_mask: np.ndarray  # (H,W) bool: inside a block and not dead
    source: str = ""
    notes: str = ""
    path: str = ""

    @property
    def num_live(self) -> int:
        return int(self.live_mask.sum())

    def to_dict(self) -> dict:
        d = {"layout_id": self.layout_id, "hand": self.hand, "grid": list(self.grid),
             "value": dict(self.value), "blocks": [b.to_dict() for b in self.blocks],
             "dead_cells": self.dead_cells.tolist(), "bend_cells": self.bend_cells.tolist(),
             "source": self.source}
        if self.notes:
            d["notes"] = self.notes
        return d


def _cells(raw: list, grid: tuple[int, int], what: str, where: str) -> np.ndarray:
    cells = np.asarray(raw, dtype=np.int64).reshape(-1, 2)
    bad = (cells[:, 0] >= grid[0]) | (cells[:, 1] >= grid[1])
    if bad.any():
        raise ValueError(f"{where}: {what} cell {cells[bad][0].tolist()} is outside the {grid[0]}x{grid[1]} grid")
    if len({tuple(c) for c in cells.tolist()}) != len(cells):
        raise ValueError(f"{where}: {what} lists a cell twice")
    return cells


def parse_layout(doc: dict, where: str = "<layout>", canonical: CanonicalHand | None = None) -> Layout:
    """Validate a layout document (schema + geometry) and build a `Layout`."""
    validate_json(doc, "layout", where)
    canon = canonical or load_canonical()
    grid = (int(doc["grid"][0]), int(doc["grid"][1]))
    owner = np.full(grid, -1, np.int64)  # block index of each cell, -1 = none
    blocks: list[Block] = []
    targets: dict[str, str] = {}
    for i, spec in enumerate(doc["blocks"]):
        b = Block(name=spec["name"], place=spec["place"], rows=tuple(spec["rows"]), cols=tuple(spec["cols"]),
                  flip_x=bool(spec.get("flip_x", False)), flip_y=bool(spec.get("flip_y", False)))
        tag = f"{where}: block {b.name!r}"
        if any(x.name == b.name for x in blocks):
            raise ValueError(f"{tag}: duplicate block name")
        if b.place not in canon.places and b.place not in canon.groups:
            raise ValueError(f"{tag}: unknown place {b.place!r} (places: {sorted(canon.places)}; groups: {list(GROUPS)})")
        if b.rows[0] > b.rows[1] or b.cols[0] > b.cols[1]:
            raise ValueError(f"{tag}: ranges must be [first, last] with first <= last, got rows {list(b.rows)} cols {list(b.cols)}")
        if b.rows[1] >= grid[0] or b.cols[1] >= grid[1]:
            raise ValueError(f"{tag}: rows {list(b.rows)} cols {list(b.cols)} lie outside the {grid[0]}x{grid[1]} grid")
        x0, y0, x1, y1 = canon.target_rect(b.place)
        if b.shape[0] > y1 - y0 or b.shape[1] > x1 - x0:
            raise ValueError(f"{tag}: {b.shape[0]}x{b.shape[1]} cells do not fit the {y1 - y0}x{x1 - x0} px of {b.place!r}")
        region = owner[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1]
        if (region >= 0).any():
            other = blocks[int(region[region >= 0][0])].name
            raise ValueError(f"{tag}: overlaps block {other!r} in the raw grid")
        # Two blocks drawing on the same pixels would overwrite each other.
        for t, name in targets.items():
            if t == b.place or t.split(".")[0] == b.place or b.place.split(".")[0] == t:
                raise ValueError(f"{tag}: target {b.place!r} overlaps target {t!r} of block {name!r}")
        targets[b.place] = b.name
        region[...] = i
        blocks.append(b)

    dead = _cells(doc["dead_cells"], grid, "dead_cells", where)
    bend = _cells(doc["bend_cells"], grid, "bend_cells", where)
    if len(dead) and (owner[dead[:, 0], dead[:, 1]] < 0).any():
        c = dead[owner[dead[:, 0], dead[:, 1]] < 0][0].tolist()
        raise ValueError(f"{where}: dead cell {c} is not inside any block (only cells inside blocks can be dead)")
    live = owner >= 0
    live[dead[:, 0], dead[:, 1]] = False
    if len(bend) and live[bend[:, 0], bend[:, 1]].any():
        c = bend[live[bend[:, 0], bend[:, 1]]][0]
        raise ValueError(f"{where}: bend cell {c.tolist()} is a live pressure cell of block "
                         f"{blocks[int(owner[c[0], c[1]])].name!r}")
    for i, b in enumerate(blocks):
        if not live[owner == i].any():
            raise ValueError(f"{where}: block {b.name!r} has no live cell")
    return Layout(layout_id=doc["layout_id"], hand=doc["hand"], grid=grid, value=dict(doc["value"]),
                  blocks=tuple(blocks), dead_cells=_frozen(dead), bend_cells=_frozen(bend),
                  live_mask=_frozen(live), source=doc.get("source", ""), notes=doc.get("notes", ""),
                  path=where)


def layout_path(layout_id_or_path: str | Path) -> Path:
    """A shipped layout id (`opentouch_right_16x16`) or a path to a JSON file."""
    s = str(layout_id_or_path)
    p = Path(s)
    if s.endswith(".json") or p.is_file() or "/" in s:
        return p
    return LAYOUTS_DIR / f"{s}.json"


def load_layout(layout_id_or_path: str | Path) -> Layout:
    path = layout_path(layout_id_or_path)
    if not path.is_file():
        raise FileNotFoundError(f"layout {str(layout_id_or_path)!r} not found (looked at {path}; "
                                f"shipped layouts: {list_layouts()})")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON: {e}") from None
    layout = parse_layout(doc, str(path))
    if path.parent == LAYOUTS_DIR and path.stem != layout.layout_id:
        raise ValueError(f"{path}: layout_id {layout.layout_id!r} must equal the file name")
    return layout


def list_layouts() -> list[str]:
    """Ids of the shipped glove layouts (every JSON in schemas/layouts/ but the template)."""
    return sorted(p.stem for p in LAYOUTS_DIR.glob("*.json") if p.name != CANONICAL_FILE)


# --------------------------------------------------------------------------- CLI

# BGR colours per part id (0 = background), for `htdata layouts render`.
_PART_BGR = np.array([[0, 0, 0], [60, 60, 230], [60, 200, 60], [230, 140, 40], [200, 60, 200],
                      [40, 200, 230], [150, 150, 150]], np.uint8)


def render_layout_png(layout: Layout, out: Path, scale: int = 2) -> None:
    """Two panels: the canonical regions coloured by part, and this glove's coverage."""
    import cv2

    from htdata.rasterise import Rasteriser

    canon = load_canonical()
    r = Rasteriser(layout, canonical=canon)
    regions = _PART_BGR[canon.part_map].astype(np.float32)
    regions *= np.where(canon.region_map % 2 == 1, 1.0, 0.7)[..., None]  # tell neighbouring regions apart
    cov = np.zeros_like(regions)
    inside = canon.region_map > 0
    cov[inside] = regions[inside] * 0.25
    cov[r.coverage == 1] = 255
    img = np.concatenate([regions, np.full((CANVAS, 4, 3), 255, np.float32), cov], axis=1).astype(np.uint8)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    text = f"{layout.layout_id}  coverage {r.coverage_fraction:.3f}"
    cv2.putText(img, text, (6, img.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), img):
        raise OSError(f"could not write {out}")


def describe(layout: Layout) -> dict:
    """Numbers shown by `htdata layouts`: live taxels, bend cells, coverage."""
    from htdata.rasterise import Rasteriser

    r = Rasteriser(layout)
    return {"layout_id": layout.layout_id, "hand": layout.hand, "grid": f"{layout.grid[0]}x{layout.grid[1]}",
            "live": layout.num_live, "bend": len(layout.bend_cells), "blocks": len(layout.blocks),
            "coverage": r.coverage_fraction}


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = ("examples:\n  htdata layouts\n  htdata layouts check my_glove.json\n"
                     "  htdata layouts render opentouch_right_16x16 out.png")
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.add_parser("list", help="list shipped layouts (default)")
    p = sub.add_parser("check", help="validate a layout JSON file and print its coverage")
    p.add_argument("file", help="path to a layout JSON")
    p = sub.add_parser("render", help="draw the region map + coverage of a layout as a PNG")
    p.add_argument("layout", help="layout id or path to a layout JSON")
    p.add_argument("out", help="output .png path")


def _print_rows(rows: list[dict]) -> None:
    print(f"{'layout':32s} {'hand':5s} {'grid':6s} {'blocks':>6s} {'live':>5s} {'bend':>5s} {'coverage':>8s}")
    for d in rows:
        print(f"{d['layout_id']:32s} {d['hand']:5s} {d['grid']:6s} {d['blocks']:6d} {d['live']:5d} "
              f"{d['bend']:5d} {d['coverage']:8.3f}")


def run(args: argparse.Namespace) -> int:
    action = getattr(args, "action", None) or "list"
    try:
        if action == "list":
            _print_rows([describe(load_layout(i)) for i in list_layouts()])
            print("coverage = fraction of the canonical hand's pixels this glove has a sensor under")
        elif action == "check":
            _print_rows([describe(load_layout(args.file))])
            print(f"OK: {args.file}")
        elif action == "render":
            render_layout_png(load_layout(args.layout), Path(args.out))
            print(f"wrote {args.out}")
    except (ValueError, FileNotFoundError, OSError) as e:
        print(f"error: {e}")
        return 1
    return 0
