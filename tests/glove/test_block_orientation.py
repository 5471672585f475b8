"""Per-block orientation (transpose, rotate, flip_x, flip_y): drawn where the docs say, round-trip exact."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from htdata.glove.layouts import load_canonical, load_layout, parse_layout
from htdata.glove.rasterise import BILINEAR_ROUNDTRIP_BOUND, Rasteriser

# Every orientation the fields can express: 2 transposes x 4 rotations x 4 flip pairs (the 8 dihedral
# maps, each reached several ways).
ORIENTATIONS = list(itertools.product((False, True), (0, 90, 180, 270), (False, True), (False, True)))
GRID = (6, 9)
# A 3x5 block: not square, so a wrong transpose/rotation changes the drawn shape, not only the order.
BLOCK_ROWS, BLOCK_COLS = (1, 3), (2, 6)
PLACE = "palm.upper_radial"     # 88 x 48 px: holds 3x5 and 5x3 with whole pixels per cell


def _layout(transpose: bool, rotate: int, flip_x: bool, flip_y: bool):
    block = {"name": "b", "place": PLACE, "rows": list(BLOCK_ROWS), "cols": list(BLOCK_COLS),
             "flip_x": flip_x, "flip_y": flip_y, "rotate": rotate, "transpose": transpose}
    doc = {"layout_id": "oriented", "hand": "right", "grid": list(GRID), "value": {"convention": "direct", "max": 1.0},
           "blocks": [block], "dead_cells": [], "bend_cells": [], "source": "test"}
    return parse_layout(doc, "oriented.json")


def _expected_display(raw_block: np.ndarray, transpose, rotate, flip_x, flip_y) -> np.ndarray:
    """The documented order, with numpy: transpose, rotate clockwise, then the canvas flips."""
    a = raw_block.T if transpose else raw_block
    a = np.rot90(a, k=-(rotate // 90))          # negative k = clockwise
    if flip_x:
        a = a[:, ::-1]
    if flip_y:
        a = a[::-1, :]
    return a


def _asymmetric_grid() -> np.ndarray:
    """Every cell a different value: any mirror or rotation of it differs from it."""
    g = np.full((1, *GRID), np.nan, np.float32)
    n = (BLOCK_ROWS[1] - BLOCK_ROWS[0] + 1) * (BLOCK_COLS[1] - BLOCK_COLS[0] + 1)
    g[0, BLOCK_ROWS[0]:BLOCK_ROWS[1] + 1, BLOCK_COLS[0]:BLOCK_COLS[1] + 1] = \
        (np.arange(1, n + 1, dtype=np.float32) / (n + 1)).reshape(3, 5)
    return g


@pytest.mark.parametrize("transpose, rotate, flip_x, flip_y", ORIENTATIONS)
def test_block_is_drawn_in_the_documented_orientation(transpose, rotate, flip_x, flip_y):
    layout = _layout(transpose, rotate, flip_x, flip_y)
    r = Rasteriser(layout, mode="nearest")
    g = _asymmetric_grid()
    m = r.render(g)[0]
    want = _expected_display(g[0, BLOCK_ROWS[0]:BLOCK_ROWS[1] + 1, BLOCK_COLS[0]:BLOCK_COLS[1] + 1],
                             transpose, rotate, flip_x, flip_y)
    assert layout.blocks[0].display_shape == want.shape
    x0, y0, x1, y1 = load_canonical().places[PLACE]
    dh, dw = want.shape
    # The centre pixel of each display cell shows that cell's value.
    for i in range(dh):
        for j in range(dw):
            py = y0 + int((i + 0.5) * (y1 - y0) / dh)
            px = x0 + int((j + 0.5) * (x1 - x0) / dw)
            assert m[py, px] == pytest.approx(want[i, j]), (i, j)


@pytest.mark.parametrize("transpose, rotate, flip_x, flip_y", ORIENTATIONS)
@pytest.mark.parametrize("mode", ["nearest", "bilinear"])
def test_roundtrip_taxel_map_taxel_every_orientation(transpose, rotate, flip_x, flip_y, mode):
    r = Rasteriser(_layout(transpose, rotate, flip_x, flip_y), mode=mode)
    g = _asymmetric_grid()
    back = r.sample(r.render(g))
    live = r.layout.live_mask
    err = np.abs(back - g)[:, live]
    assert np.isnan(back[:, ~live]).all()
    if mode == "nearest":
        assert err.max() < 1e-6      # exact: footprint means of one value
    else:
        assert err.max() < BILINEAR_ROUNDTRIP_BOUND


@pytest.mark.parametrize("transpose, rotate, flip_x, flip_y", ORIENTATIONS)
def test_raw_cell_and_display_cell_are_inverse(transpose, rotate, flip_x, flip_y):
    b = _layout(transpose, rotate, flip_x, flip_y).blocks[0]
    dh, dw = b.display_shape
    i, j = np.mgrid[0:dh, 0:dw]
    rr, cc = b.raw_cell(i.ravel(), j.ravel())
    assert sorted(zip(rr.tolist(), cc.tolist())) == [(r, c) for r in range(1, 4) for c in range(2, 7)]
    back_i, back_j = b.display_cell(rr, cc)
    assert np.array_equal(back_i, i.ravel()) and np.array_equal(back_j, j.ravel())


def test_identity_orientation_keeps_documents_and_maps_unchanged():
    """Defaults are the old behaviour: shipped layouts keep their exact to_dict() (dataset layout copies)."""
    for lid in ("opentouch_right_16x16", "touchanything_left_21x21", "touchanything_right_21x21"):
        lay = load_layout(lid)
        on_disk = json.loads(open(lay.path).read())
        assert lay.to_dict() == on_disk
        assert all(b.rotate == 0 and not b.transpose for b in lay.blocks)


def test_rotated_block_must_fit_as_drawn():
    """A 2x20 block fits little.distal (26 x 36 px) lying down only if it is drawn 20 wide: rotated, it does not."""
    doc = {"layout_id": "tall", "hand": "right", "grid": [4, 40], "value": {"convention": "direct", "max": 1.0},
           "blocks": [{"name": "strip", "place": "little.distal", "rows": [0, 1], "cols": [0, 29]}],
           "dead_cells": [], "bend_cells": [], "source": "test"}
    parse_layout(doc, "tall.json")
    doc["blocks"][0]["rotate"] = 90
    with pytest.raises(ValueError, match=r"strip.*30x2 cells \(as drawn, after transpose/rotate\) do not fit"):
        parse_layout(doc, "tall.json")


def test_schema_refuses_other_angles():
    doc = {"layout_id": "bad", "hand": "right", "grid": [4, 4], "value": {"convention": "direct", "max": 1.0},
           "blocks": [{"name": "b", "place": "palm", "rows": [0, 1], "cols": [0, 1], "rotate": 45}],
           "dead_cells": [], "bend_cells": [], "source": "test"}
    with pytest.raises(ValueError, match="rotate"):
        parse_layout(doc, "bad.json")


def test_docs_rotated_example_is_valid_and_rotated():
    """docs/LAYOUTS.md's rotated-block example parses, and its thumb block is drawn along the place's long axis."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "LAYOUTS.md").read_text()
    start = text.index("```json", text.index("## Rotated blocks"))
    doc = json.loads(text[start + len("```json"):text.index("```", start + 7)])
    lay = parse_layout(doc, "LAYOUTS.md rotated example")
    thumb = next(b for b in lay.blocks if b.place == "thumb.distal")
    assert thumb.shape[1] > thumb.shape[0]                 # long axis along the raw columns
    assert thumb.display_shape[0] > thumb.display_shape[1]  # drawn along the (tall) thumb place
    Rasteriser(lay)


@pytest.mark.parametrize("rotate, corner", [(0, "top_left"), (90, "top_right"), (180, "bottom_right"),
                                            (270, "bottom_left")])
def test_layouts_render_shows_the_first_cell_where_the_rotation_puts_it(tmp_path, rotate, corner):
    """`htdata layouts render`: the yellow first cell moves round the place as the block is rotated."""
    import cv2

    from htdata.cli import main
    from htdata.commands.layouts import RENDER_BAND

    doc = _layout(False, rotate, False, False).to_dict()
    doc["layout_id"] = "oriented"
    path = tmp_path / "oriented.json"
    path.write_text(json.dumps(doc))
    png = tmp_path / "o.png"
    assert main(["layouts", "render", str(path), str(png)]) == 0
    img = cv2.imread(str(png))[RENDER_BAND:]   # the title and legend band sits above the panels
    x0, y0, x1, y1 = load_canonical().places[PLACE]
    off = 2 * (224 + 4)              # right panel starts after the regions panel and a 4 px separator (scale 2)
    ys = {"top": y0 + 2, "bottom": y1 - 3}[corner.split("_")[0]]
    xs = {"left": x0 + 2, "right": x1 - 3}[corner.split("_")[1]]
    yellow = np.array([0, 230, 255])
    assert np.abs(img[2 * ys, off + 2 * xs].astype(int) - yellow).max() <= 2
    others = [(y0 + 2, x0 + 2), (y0 + 2, x1 - 3), (y1 - 3, x1 - 3), (y1 - 3, x0 + 2)]
    for (y, x) in others:
        if (y, x) != (ys, xs):
            assert np.abs(img[2 * y, off + 2 * x].astype(int) - yellow).max() > 2
