"""Rectangular blocks from a mask of moving cells: where a connected sensor splits into parts.

On a real knit glove the palm touches every finger strip and the thumb in
the raw grid, so the moving cells are ONE connected shape and its bounding
box is the whole grid. `cut_blocks` cuts it into rectangles the way the
sensor is built:

- along EMPTY LINES: a row or column of a part's box without a moving cell
  (the unsensed rows between finger strips) splits the part there;
- where the shape NARROWS or changes pattern: among the straight cuts across
  a part, the one after which the two sides (each split along its own empty
  lines again) leave the fewest still cells inside their boxes. Palm | finger
  strips: the strips' side then falls apart along the gap rows; palm | thumb:
  the thumb's side shrinks to the thumb's columns. A cut is taken when it
  frees at least CUT_SHARE of the part's box; a still patch inside an area
  (taxels nobody pressed) frees less than that, so the area stays whole.

Parts with fewer than MIN_BLOCK_CELLS moving cells are left out (a stray
patch is no sensor area). `grow_blocks` then lets each block take the next
row or column beside it while at least GROW_SHARE of that line's cells moved
in some recording and moved in at least GROW_SUPPORT x as many recordings as
the block's own cells (hysteresis: a block found on cells that moved in
several recordings continues over cells pressed once; a raw row that moved
once beside a block pressed in many recordings, a row shifting with a hard
press, does not). `join_lengthwise` joins a strip that was cut lengthwise
(a line or two pressed along one edge of a finger strip, issue 43: the
strip is then two thin blocks side by side) back into one. `split_strips` cuts a strip k times as long as it is wide
into k near-square blocks (while the blocks still find places): the
canonical hand draws a finger over three places, one block per place.
"""

from __future__ import annotations

import numpy as np

CUT_SHARE = 0.10         # a narrowing cut must free this share of the part's box (still cells)
MIN_BLOCK_CELLS = 8      # a part with fewer moving cells is no sensor area
GROW_SHARE = 0.5         # a block grows by a line when this share of the line moved in some recording ...
GROW_SUPPORT = 0.25      # ... in at least this share of the recordings the block's own cells moved in (mean)
STRIP_MIN_WIDTH = 3      # a box narrower than this is an edge or a fragment, not a strip to cut into places

Box = tuple[int, int, int, int]   # inclusive (r0, r1, c0, c1)


def _components(mask: np.ndarray) -> list[np.ndarray]:
    from scipy import ndimage

    labels, n = ndimage.label(mask)
    return [labels == k for k in range(1, n + 1)]


def _box(mask: np.ndarray) -> Box:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])


def _still(parts: list[np.ndarray]) -> int:
    """Cells inside the parts' boxes that did not move."""
    total = 0
    for p in parts:
        r0, r1, c0, c1 = _box(p)
        total += (r1 - r0 + 1) * (c1 - c0 + 1) - int(p.sum())
    return total


def _empty_line_parts(part: np.ndarray) -> list[np.ndarray]:
    """The part split along every empty row / column of its box, recursively (connected pieces)."""
    r0, r1, c0, c1 = _box(part)
    box = part[r0:r1 + 1, c0:c1 + 1]
    empty_rows, empty_cols = ~box.any(axis=1), ~box.any(axis=0)
    if not empty_rows.any() and not empty_cols.any():
        return [part]
    band = np.zeros(part.shape, np.int64)
    band[r0:r1 + 1, c0:c1 + 1] = np.cumsum(empty_rows)[:, None] * (len(empty_cols) + 1) + np.cumsum(empty_cols)[None, :]
    out = []
    for v in np.unique(band[part]):
        for piece in _components(part & (band == v)):
            out.extend(_empty_line_parts(piece))
    return out


def _best_cut(part: np.ndarray) -> tuple[int, list[np.ndarray]]:
    """(still cells freed, pieces) of the best straight cut across the part's box (0, [] when none frees any)."""
    r0, r1, c0, c1 = _box(part)
    before = _still([part])
    best: tuple[int, list[np.ndarray]] = (0, [])
    index = np.indices(part.shape)
    for axis, (lo, hi) in ((0, (r0, r1)), (1, (c0, c1))):
        for i in range(lo, hi):
            pieces = [q for side in (part & (index[axis] <= i), part & (index[axis] > i))
                      for p in _components(side) for q in _empty_line_parts(p)]
            freed = before - _still(pieces)
            if freed > best[0]:
                best = (freed, pieces)
    return best


def _cut(part: np.ndarray, out: list[np.ndarray]) -> None:
    pieces = _empty_line_parts(part)
    if len(pieces) > 1:
        for p in pieces:
            _cut(p, out)
        return
    r0, r1, c0, c1 = _box(part)
    freed, pieces = _best_cut(part)
    if not pieces or freed < CUT_SHARE * (r1 - r0 + 1) * (c1 - c0 + 1):
        out.append(part)
        return
    for p in pieces:
        _cut(p, out)


def cut_blocks(mask: np.ndarray) -> list[Box]:
    """Boxes of the parts of `mask` (module docstring), parts under MIN_BLOCK_CELLS moving cells left out; boxes
    of interleaved parts that overlap are merged until none do."""
    parts: list[np.ndarray] = []
    for component in _components(np.asarray(mask, bool)):
        _cut(component, parts)
    boxes = [_box(p) for p in parts if p.sum() >= MIN_BLOCK_CELLS]
    merged = True
    while merged:
        merged = False
        for i, j in ((i, j) for i in range(len(boxes)) for j in range(i + 1, len(boxes))):
            a, b = boxes[i], boxes[j]
            if _overlaps(a, b):
                boxes[i] = (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                del boxes[j]
                merged = True
                break
    return sorted(boxes)


def _overlaps(a: Box, b: Box) -> bool:
    return a[0] <= b[1] and b[0] <= a[1] and a[2] <= b[3] and b[2] <= a[3]


def grow_blocks(boxes: list[Box], moved: np.ndarray, support: np.ndarray) -> list[Box]:
    """Each box grown line by line over `moved` cells (module docstring); `support` = recordings each cell moved in."""
    boxes = [list(b) for b in boxes]
    grid = moved.shape
    grown = True
    while grown:
        grown = False
        for k, b in enumerate(boxes):
            for side in range(4):
                nb = list(b)
                if side == 0 and b[0] > 0:
                    nb[0] -= 1
                    line = (nb[0], slice(b[2], b[3] + 1))
                elif side == 1 and b[1] < grid[0] - 1:
                    nb[1] += 1
                    line = (nb[1], slice(b[2], b[3] + 1))
                elif side == 2 and b[2] > 0:
                    nb[2] -= 1
                    line = (slice(b[0], b[1] + 1), nb[2])
                elif side == 3 and b[3] < grid[1] - 1:
                    nb[3] += 1
                    line = (slice(b[0], b[1] + 1), nb[3])
                else:
                    continue
                own = float(support[b[0]:b[1] + 1, b[2]:b[3] + 1].mean())
                if (moved[line].mean() >= GROW_SHARE and support[line].mean() >= GROW_SUPPORT * own
                        and not any(_overlaps(tuple(nb), tuple(o)) for j, o in enumerate(boxes) if j != k)):
                    boxes[k] = b = nb
                    grown = True
    return sorted(tuple(b) for b in boxes)


def _touching(thin: Box, other: Box, axis: int, side: int) -> bool:
    """`other` lies against `thin`'s long side (`axis` 0: above / below it, 1: left / right; `side` -1 or 1) and
    overlaps it along its length."""
    lo, hi = (0, 1) if axis == 0 else (2, 3)
    along = (2, 3) if axis == 0 else (0, 1)
    against = other[hi] == thin[lo] - 1 if side < 0 else other[lo] == thin[hi] + 1
    return against and other[along[0]] <= thin[along[1]] and thin[along[0]] <= other[along[1]]


def join_lengthwise(boxes: list[Box]) -> list[Box]:
    """Boxes joined where a strip was cut LENGTHWISE: a box thinner than STRIP_MIN_WIDTH (a line or two of a strip
    pressed on its own, e.g. along one edge) and the boxes against its long side on one side are one box, when
    that box overlaps no other. A strip is then cut only across, into places along the finger (`split_strips`)."""
    out = list(boxes)
    joined = True
    while joined:
        joined = False
        for thin in sorted(out, key=lambda b: min(b[1] - b[0], b[3] - b[2])):
            h, w = thin[1] - thin[0] + 1, thin[3] - thin[2] + 1
            if min(h, w) >= STRIP_MIN_WIDTH:
                continue
            axis = 0 if w > h else 1            # its long side runs along a row (0) or a column (1)
            for side in (1, -1):
                mates = [b for b in out if b != thin and _touching(thin, b, axis, side)]
                if not mates:
                    continue
                group = [thin, *mates]
                union = (min(b[0] for b in group), max(b[1] for b in group),
                         min(b[2] for b in group), max(b[3] for b in group))
                if not any(_overlaps(union, b) for b in out if b not in group):
                    out = [b for b in out if b not in group] + [union]
                    joined = True
                    break
            if joined:
                break
    return sorted(out)


def split_strips(boxes: list[Box], most: int) -> list[Box]:
    """A box k >= 2 times as long as it is wide (and at least STRIP_MIN_WIDTH wide: a thinner box is an edge or a
    fragment) cut across into k near-square boxes, most elongated first, while there are at most `most` boxes."""
    out = list(boxes)
    for box in sorted(boxes, key=lambda b: -max(b[1] - b[0] + 1, b[3] - b[2] + 1) / min(b[1] - b[0] + 1, b[3] - b[2] + 1)):
        r0, r1, c0, c1 = box
        h, w = r1 - r0 + 1, c1 - c0 + 1
        k = max(h, w) // min(h, w)
        if k < 2 or min(h, w) < STRIP_MIN_WIDTH or len(out) + k - 1 > most:
            continue
        out.remove(box)
        edges = np.linspace(0, max(h, w), k + 1).round().astype(int)
        for a, z in zip(edges[:-1], edges[1:]):
            out.append((r0 + a, r0 + z - 1, c0, c1) if h > w else (r0, r1, c0 + a, c0 + z - 1))
    return sorted((int(a), int(b), int(c), int(d)) for a, b, c, d in out)
