"""Canonical hand template and glove layouts, both plain JSON data.

`schemas/layouts/canonical_hand.json` places anatomical regions on a 224x224
right-hand palmar canvas; `schemas/layouts/<layout_id>.json` says which
rectangle ("block") of a glove's raw taxel grid lands on which place. A new
glove is registered by writing one such file (docs/LAYOUTS.md); this module
finds, loads and validates both (the `htdata layouts` command is
htdata/commands/layouts.py).

Where glove layouts are found (`layout_dirs`), first hit wins:
1. folders given by the caller (`htdata ingest/layouts --layouts DIR`),
2. folders in the HTDATA_LAYOUTS environment variable (os.pathsep-separated),
3. the shipped `schemas/layouts/`.
A layout may also be named by a path to its JSON file (`load_layout(path)`;
relative paths are taken from `base`, e.g. the pipeline file's or the
recording's folder). Parsed layouts are cached per (file, mtime, size).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from htdata.errors import LayoutNotFound
from htdata.format import CANONICAL_FILE, CANVAS
from htdata.resources import LAYOUTS_DIR, validate_json

LAYOUTS_ENV = "HTDATA_LAYOUTS"
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


def layout_dirs(extra: tuple[str | Path, ...] | list = ()) -> list[Path]:
    """Folders searched for a layout id, in order: `extra`, then $HTDATA_LAYOUTS, then the shipped folder."""
    env = [d for d in os.environ.get(LAYOUTS_ENV, "").split(os.pathsep) if d]
    out: list[Path] = []
    for d in [*extra, *env, LAYOUTS_DIR]:
        p = Path(d).expanduser().resolve()
        if p not in out:
            out.append(p)
    return out


def is_layout_path(name: str | Path) -> bool:
    """True when `name` names a JSON file rather than a layout id."""
    s = str(name)
    return isinstance(name, Path) or s.endswith(".json") or "/" in s or os.sep in s


def resolve_layout(name: str | Path, dirs: tuple | list = (), base: str | Path | None = None) -> Path:
    """The JSON file of a layout id (searched in `layout_dirs(dirs)`) or of a path (relative to `base`).

    Raises LayoutNotFound with a one-line message naming where it looked and
    the layouts that exist there.
    """
    if is_layout_path(name):
        p = Path(name).expanduser()
        if not p.is_absolute() and base is not None:
            p = Path(base) / p
        if p.is_file():
            return p.resolve()
        raise LayoutNotFound(f"layout file {str(name)!r} not found (looked at {p}; "
                             f"available layouts: {list_layouts(dirs)})")
    searched = layout_dirs(dirs)
    for d in searched:
        p = d / f"{name}.json"
        if p.is_file() and p.name != CANONICAL_FILE:
            return p
    raise LayoutNotFound(f"layout {str(name)!r} not found (looked in {', '.join(str(d) for d in searched)}; "
                         f"available layouts: {list_layouts(dirs)}); add its JSON to one of those folders, "
                         f"pass --layouts DIR or set {LAYOUTS_ENV}")


@lru_cache(maxsize=128)
def _load_layout_file(path: str, mtime_ns: int, size: int) -> Layout:
    """Parse one file version once per process (mtime and size are part of the key)."""
    try:
        doc = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON: {e}") from None
    return parse_layout(doc, path)


def load_layout(name: str | Path, dirs: tuple | list = (), base: str | Path | None = None) -> Layout:
    """A validated layout from its id or JSON path (see `resolve_layout`), cached per file version.

    A layout found by id must carry that id (`<id>.json` holds layout_id <id>).
    """
    path = resolve_layout(name, dirs, base)
    st = path.stat()
    layout = _load_layout_file(str(path), st.st_mtime_ns, st.st_size)
    if not is_layout_path(name) and layout.layout_id != str(name):
        raise ValueError(f"{path}: layout_id {layout.layout_id!r} must equal the file name ({str(name)!r})")
    return layout


def list_layouts(dirs: tuple | list = ()) -> list[str]:
    """Ids of every glove layout on the search path (every JSON there but the template)."""
    ids: set[str] = set()
    for d in layout_dirs(dirs):
        if d.is_dir():
            ids.update(p.stem for p in d.glob("*.json") if p.name != CANONICAL_FILE)
    return sorted(ids)
