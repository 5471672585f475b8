"""Rectangular blocks from a connected mask of moving cells (htdata/glove/blockcuts.py)."""

from __future__ import annotations

import numpy as np

from htdata.glove.blockcuts import MIN_BLOCK_CELLS, cut_blocks, grow_blocks, split_strips

PALM = (0, 22, 0, 18)
STRIPS = [(0, 3, 19, 30), (6, 9, 19, 30), (11, 14, 19, 30), (19, 22, 19, 30)]
THUMB = (23, 31, 6, 12)


def _paint(boxes, shape=(32, 32)) -> np.ndarray:
    m = np.zeros(shape, bool)
    for r0, r1, c0, c1 in boxes:
        m[r0:r1 + 1, c0:c1 + 1] = True
    return m


def _connected_glove() -> np.ndarray:
    """A 32x32 knit glove's raw grid: the palm touches every finger strip (gap rows between them) and the thumb."""
    return _paint([PALM, *STRIPS, THUMB])


def test_a_connected_glove_is_cut_into_palm_finger_strips_and_thumb():
    mask = _connected_glove()
    assert cut_blocks(mask) == sorted([PALM, *STRIPS, THUMB])
    # taxels nobody pressed inside the palm and a strip do not cut them: the area stays whole
    holes = mask.copy()
    holes[14:21, 0:4] = False                    # a corner of the palm
    holes[8:12, 7:10] = False                    # a patch inside it
    holes[0:3, 25] = False                       # part of a strip's column
    assert cut_blocks(holes) == sorted([PALM, *STRIPS, THUMB])


def test_empty_lines_split_and_stray_patches_are_left_out():
    mask = _paint([(0, 3, 0, 11), (5, 8, 0, 11), (20, 21, 20, 21)])     # two strips, a gap row, a 2x2 patch
    assert cut_blocks(mask) == [(0, 3, 0, 11), (5, 8, 0, 11)]
    assert (20 - 20 + 1) * (21 - 20 + 1) < MIN_BLOCK_CELLS
    assert cut_blocks(np.zeros((8, 8), bool)) == []


def test_blocks_grow_over_cells_pressed_once_but_not_over_a_row_that_moved_once():
    support = np.zeros((32, 32), np.int64)
    support[0:4, 19:25] = 4                      # a finger strip found in four recordings ...
    support[0:4, 25:31] = 1                      # ... continues over taxels pressed in one
    support[26, :] = 1                           # a raw row shifting once with a hard press
    support[27:32, 6:13] = 4                     # beside the thumb, pressed in four
    support[26, 6:13] = 4
    grown = grow_blocks([(0, 3, 19, 24), (27, 31, 6, 12)], support > 0, support)
    assert grown == [(0, 3, 19, 30), (26, 31, 6, 12)]


def test_strips_become_near_square_blocks_while_they_find_places():
    boxes = [PALM, *STRIPS, THUMB, (24, 25, 20, 29)]                     # the last one is 2 wide: a fragment
    cut = split_strips(boxes, most=18)
    assert len(cut) == 1 + 4 * 3 + 1 + 1
    assert (0, 3, 19, 22) in cut and (0, 3, 23, 26) in cut and (0, 3, 27, 30) in cut
    assert PALM in cut and THUMB in cut and (24, 25, 20, 29) in cut
    assert _paint(cut).sum() == _paint(boxes).sum()
    assert len(split_strips(boxes, most=9)) <= 9                          # never more blocks than places
