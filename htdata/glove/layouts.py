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

import difflib
import json
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from htdata._moved import moved_name
from htdata.errors import ConfigError, LayoutNotFound
from htdata.format.table import CANONICAL_FILE
from htdata.glove.canonical import GROUPS, CanonicalHand, frozen, load_canonical
from htdata.resources import LAYOUTS_DIR, validate_json

LAYOUTS_ENV = "HTDATA_LAYOUTS"


# --------------------------------------------------------------------------- glove layouts


ROTATIONS = (0, 90, 180, 270)


@dataclass(frozen=True)
class Block:
    """A rectangle of the raw grid (inclusive ranges) drawn onto one place or group.

    Orientation: the block's raw cells (row-major, as stored) become the
    array drawn into the place's rectangle (top row first) by, in this order,
    1. `transpose`: raw rows become columns,
    2. `rotate`: 0/90/180/270 degrees clockwise as seen on the canvas,
    3. `flip_x` (mirror left-right) and `flip_y` (mirror top-bottom), in
       canvas axes.
    The defaults (no transpose, rotate 0, no flips) draw raw row 0 at the
    top and raw column 0 at the left.
    """

    name: str
    place: str
    rows: tuple[int, int]
    cols: tuple[int, int]
    flip_x: bool = False
    flip_y: bool = False
    rotate: int = 0
    transpose: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the block in the raw grid."""
        return (self.rows[1] - self.rows[0] + 1, self.cols[1] - self.cols[0] + 1)

    @property
    def display_shape(self) -> tuple[int, int]:
        """(rows, cols) of the block as drawn on the canvas (after transpose and rotation)."""
        h, w = self.shape
        return (w, h) if self.transpose != (self.rotate in (90, 270)) else (h, w)

    def raw_cell(self, display_rows: np.ndarray, display_cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw (row, col) of the cell drawn at (row, col) counted from the top-left of the place."""
        dh, dw = self.display_shape
        r = np.asarray(display_rows)
        c = np.asarray(display_cols)
        # Undo the steps in reverse order: flips, rotation, transpose.
        if self.flip_y:
            r = dh - 1 - r
        if self.flip_x:
            c = dw - 1 - c
        ah, aw = (dw, dh) if self.rotate in (90, 270) else (dh, dw)   # shape before the rotation
        if self.rotate == 90:      # R[i, j] = A[ah-1-j, i]
            r, c = ah - 1 - c, r
        elif self.rotate == 180:   # R[i, j] = A[ah-1-i, aw-1-j]
            r, c = ah - 1 - r, aw - 1 - c
        elif self.rotate == 270:   # R[i, j] = A[j, aw-1-i]
            r, c = c, aw - 1 - r
        if self.transpose:
            r, c = c, r
        return self.rows[0] + r, self.cols[0] + c

    def display_cell(self, raw_rows: np.ndarray, raw_cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of `raw_cell`: where on the place (row, col from its top-left) a raw cell is drawn."""
        dh, dw = self.display_shape
        r = np.asarray(raw_rows) - self.rows[0]
        c = np.asarray(raw_cols) - self.cols[0]
        if self.transpose:
            r, c = c, r
        ah, aw = (dw, dh) if self.rotate in (90, 270) else (dh, dw)
        if self.rotate == 90:
            r, c = c, ah - 1 - r
        elif self.rotate == 180:
            r, c = ah - 1 - r, aw - 1 - c
        elif self.rotate == 270:
            r, c = aw - 1 - c, r
        if self.flip_y:
            r = dh - 1 - r
        if self.flip_x:
            c = dw - 1 - c
        return r, c

    def to_dict(self) -> dict:
        d = {"name": self.name, "place": self.place, "rows": list(self.rows),
             "cols": list(self.cols), "flip_x": self.flip_x, "flip_y": self.flip_y}
        # Only when set: layouts without orientation keep their exact documents (and dataset bytes).
        if self.rotate:
            d["rotate"] = self.rotate
        if self.transpose:
            d["transpose"] = True
        return d


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
    # (U,2) cells outside every block declared deliberately unused (no sensor, cross-talk lines)
    unused_cells: np.ndarray = field(default_factory=lambda: frozen(np.zeros((0, 2), np.int64)))

    @property
    def num_live(self) -> int:
        return int(self.live_mask.sum())

    @property
    def unmapped_mask(self) -> np.ndarray:
        """(H,W) bool: cells outside every block that are neither bend nor declared unused.

        The ingest watches these: one whose values move is a sensor the layout forgot (htdata.glove.activity).
        """
        inside = np.zeros(self.grid, bool)
        for b in self.blocks:
            inside[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = True
        out = ~inside
        for cells in (self.bend_cells, self.unused_cells):
            out[cells[:, 0], cells[:, 1]] = False
        return out

    def to_dict(self) -> dict:
        d = {"layout_id": self.layout_id, "hand": self.hand, "grid": list(self.grid),
             "value": dict(self.value), "blocks": [b.to_dict() for b in self.blocks],
             "dead_cells": self.dead_cells.tolist(), "bend_cells": self.bend_cells.tolist(),
             "source": self.source}
        if len(self.unused_cells):
            d["unused_cells"] = self.unused_cells.tolist()
        if self.notes:
            d["notes"] = self.notes
        return d


def _cells(raw: list, grid: tuple[int, int], what: str, where: str) -> np.ndarray:
    cells = np.asarray(raw, dtype=np.int64).reshape(-1, 2)
    bad = (cells[:, 0] >= grid[0]) | (cells[:, 1] >= grid[1])
    if bad.any():
        raise ConfigError(f"{where}: {what} cell {cells[bad][0].tolist()} is outside the {grid[0]}x{grid[1]} grid")
    if len({tuple(c) for c in cells.tolist()}) != len(cells):
        raise ConfigError(f"{where}: {what} lists a cell twice")
    return cells


def parse_layout(doc: dict, where: str = "<layout>", canonical: CanonicalHand | None = None) -> Layout:
    """Validate a layout document (schema + geometry) and build a `Layout`."""
    validate_json(doc, "layout", where, ConfigError)
    canon = canonical or load_canonical()
    grid = (int(doc["grid"][0]), int(doc["grid"][1]))
    owner = np.full(grid, -1, np.int64)  # block index of each cell, -1 = none
    blocks: list[Block] = []
    targets: dict[str, str] = {}
    for i, spec in enumerate(doc["blocks"]):
        b = Block(name=spec["name"], place=spec["place"], rows=tuple(spec["rows"]), cols=tuple(spec["cols"]),
                  flip_x=bool(spec.get("flip_x", False)), flip_y=bool(spec.get("flip_y", False)),
                  rotate=int(spec.get("rotate", 0)), transpose=bool(spec.get("transpose", False)))
        tag = f"{where}: block {b.name!r}"
        if any(x.name == b.name for x in blocks):
            raise ConfigError(f"{tag}: duplicate block name")
        if b.place not in canon.places and b.place not in canon.groups:
            raise ConfigError(f"{tag}: unknown place {b.place!r} (places: {sorted(canon.places)}; groups: {list(GROUPS)})")
        if b.rows[0] > b.rows[1] or b.cols[0] > b.cols[1]:
            raise ConfigError(f"{tag}: ranges must be [first, last] with first <= last, got rows {list(b.rows)} cols {list(b.cols)}")
        if b.rows[1] >= grid[0] or b.cols[1] >= grid[1]:
            raise ConfigError(f"{tag}: rows {list(b.rows)} cols {list(b.cols)} lie outside the {grid[0]}x{grid[1]} grid")
        x0, y0, x1, y1 = canon.target_rect(b.place)
        dh, dw = b.display_shape
        if dh > y1 - y0 or dw > x1 - x0:
            turned = " (as drawn, after transpose/rotate)" if b.display_shape != b.shape else ""
            raise ConfigError(f"{tag}: {dh}x{dw} cells{turned} do not fit the {y1 - y0}x{x1 - x0} px of {b.place!r}")
        region = owner[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1]
        if (region >= 0).any():
            other = blocks[int(region[region >= 0][0])].name
            raise ConfigError(f"{tag}: overlaps block {other!r} in the raw grid")
        # Two blocks drawing on the same pixels would overwrite each other.
        for t, name in targets.items():
            if t == b.place or t.split(".")[0] == b.place or b.place.split(".")[0] == t:
                raise ConfigError(f"{tag}: target {b.place!r} overlaps target {t!r} of block {name!r}")
        targets[b.place] = b.name
        region[...] = i
        blocks.append(b)

    press = doc["value"].get("press")
    if press is not None and not float(press) < float(doc["value"]["max"]):
        raise ConfigError(f"{where}: value.press {press!r} must be below value.max {doc['value']['max']!r} "
                          f"(the least rise above rest that is a press, in raw units)")
    dead = _cells(doc.get("dead_cells", []), grid, "dead_cells", where)     # optional: none by default
    bend = _cells(doc.get("bend_cells", []), grid, "bend_cells", where)
    if len(dead) and (owner[dead[:, 0], dead[:, 1]] < 0).any():
        c = dead[owner[dead[:, 0], dead[:, 1]] < 0][0].tolist()
        raise ConfigError(f"{where}: dead cell {c} is not inside any block (only cells inside blocks can be dead)")
    live = owner >= 0
    live[dead[:, 0], dead[:, 1]] = False
    if len(bend) and live[bend[:, 0], bend[:, 1]].any():
        c = bend[live[bend[:, 0], bend[:, 1]]][0]
        raise ConfigError(f"{where}: bend cell {c.tolist()} is a live pressure cell of block "
                          f"{blocks[int(owner[c[0], c[1]])].name!r}")
    for i, b in enumerate(blocks):
        if not live[owner == i].any():
            raise ConfigError(f"{where}: block {b.name!r} has no live cell")
    unused = _cells(doc.get("unused_cells", []), grid, "unused_cells", where)
    if len(unused) and (owner[unused[:, 0], unused[:, 1]] >= 0).any():
        c = unused[owner[unused[:, 0], unused[:, 1]] >= 0][0]
        raise ConfigError(f"{where}: unused cell {c.tolist()} lies inside block {blocks[int(owner[c[0], c[1]])].name!r} "
                          f"(a sensorless cell inside a block is a dead_cell)")
    if len(unused) and len(bend):
        both = {tuple(c) for c in unused.tolist()} & {tuple(c) for c in bend.tolist()}
        if both:
            raise ConfigError(f"{where}: cell {list(sorted(both)[0])} is both a bend cell and an unused cell")
    return Layout(layout_id=doc["layout_id"], hand=doc["hand"], grid=grid, value=dict(doc["value"]),
                  blocks=tuple(blocks), dead_cells=frozen(dead), bend_cells=frozen(bend),
                  live_mask=frozen(live), source=doc.get("source", ""), notes=doc.get("notes", ""),
                  path=where, unused_cells=frozen(unused))


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
    known = list_layouts(dirs)
    raise LayoutNotFound(f"layout {str(name)!r} not found{nearest_hint(str(name), known)} (looked in "
                         f"{', '.join(str(d) for d in searched)}; available layouts: {known}); add its JSON to one "
                         f"of those folders, pass --layouts DIR or set {LAYOUTS_ENV}")


def nearest_hint(name: str, known) -> str:
    """"; did you mean 'x'?" for the closest of `known` (difflib), or "" when none is close."""
    near = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
    return f"; did you mean {near[0]!r}?" if near else ""


@lru_cache(maxsize=128)
def _load_layout_file(path: str, mtime_ns: int, size: int) -> Layout:
    """Parse one file version once per process (mtime and size are part of the key)."""
    try:
        doc = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ConfigError(f"{path}: not valid JSON: {e}") from None
    return parse_layout(doc, path)


def load_layout(name: str | Path, dirs: tuple | list = (), base: str | Path | None = None) -> Layout:
    """A validated layout from its id or JSON path (see `resolve_layout`), cached per file version.

    A layout found by id must carry that id (`<id>.json` holds layout_id <id>).
    """
    path = resolve_layout(name, dirs, base)
    st = path.stat()
    layout = _load_layout_file(str(path), st.st_mtime_ns, st.st_size)
    if not is_layout_path(name) and layout.layout_id != str(name):
        raise ConfigError(f"{path}: layout_id {layout.layout_id!r} must equal the file name ({str(name)!r})")
    return layout


def list_layouts(dirs: tuple | list = ()) -> list[str]:
    """Ids of every glove layout on the search path (every JSON there but the template)."""
    ids: set[str] = set()
    for d in layout_dirs(dirs):
        if d.is_dir():
            ids.update(p.stem for p in d.glob("*.json") if p.name != CANONICAL_FILE)
    return sorted(ids)


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
