"""Canonical template + glove layouts: reference facts, geometry, validation, CLI."""

from __future__ import annotations

import copy
import json
import os

import numpy as np
import pytest

from htdata.format.canvas import CANVAS
from htdata.glove import layouts as L
from htdata.glove.canonical import parse_canonical
from htdata.glove.layouts import LAYOUTS_ENV, list_layouts, load_canonical, load_layout, parse_layout

SHIPPED = ["opentouch_right_16x16", "touchanything_left_21x21", "touchanything_right_21x21"]

# Reference facts (SOURCE_FORMATS.md), restated here as literals.
OPENTOUCH_REGION_COUNTS = {
    "p3": 6, "p2": 6, "p1": 6, "r3": 6, "r2": 6, "r1": 6, "m3": 6, "m2": 6, "m1": 6,
    "i3": 6, "i2": 6, "i1": 6, "pa4": 18, "pa3": 15, "pa1": 24, "pa2": 20, "t1": 8, "t2": 12,
}
TA_LEFT_PRESSURE = {  # block -> (rows, cols) inclusive, LEFT grid as stored
    "little_tip": ((2, 5), (1, 3)), "ring_tip": ((2, 5), (5, 7)), "middle_tip": ((2, 5), (9, 11)),
    "index_tip": ((2, 5), (13, 15)), "thumb_tip": ((6, 9), (17, 19)),
}


def _block_live_count(layout, block) -> int:
    return int(layout.live_mask[block.rows[0]:block.rows[1] + 1, block.cols[0]:block.cols[1] + 1].sum())


# --------------------------------------------------------------------------- canonical


def test_canonical_places_inside_canvas_and_disjoint():
    c = load_canonical()
    assert len(c.places) == 18
    assert sorted(c.region_ids.values()) == list(range(1, 19))
    total = 0
    for name, (x0, y0, x1, y1) in c.places.items():
        assert 0 <= x0 < x1 <= CANVAS and 0 <= y0 < y1 <= CANVAS, name
        assert (c.region_map[y0:y1, x0:x1] == c.region_ids[name]).all(), name  # no other place painted over it
        total += (x1 - x0) * (y1 - y0)
    assert total == int((c.region_map > 0).sum())  # areas add up: no overlap
    assert c.region_map.dtype == np.uint8 and c.part_map.dtype == np.uint8
    assert c.region_map.shape == c.part_map.shape == (CANVAS, CANVAS)
    frac = total / CANVAS**2
    print(f"canonical hand fills {frac:.3f} of the canvas")
    assert frac >= 0.60


def test_canonical_parts_and_groups():
    c = load_canonical()
    assert c.part_names == {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "little", 6: "palm"}
    for name, rid in c.region_ids.items():
        assert c.part_names[c.part_of_region[rid]] == name.split(".")[0]
    assert np.array_equal(c.region_map > 0, c.part_map > 0)
    for g, (x0, y0, x1, y1) in c.groups.items():
        inside = c.part_map[y0:y1, x0:x1]
        assert set(np.unique(inside).tolist()) <= {0, L.GROUPS.index(g) + 1}, g  # no other group's place


def test_canonical_anatomy():
    p = load_canonical().places
    top = {f: p[f"{f}.distal"][1] for f in ("thumb", "index", "middle", "ring", "little")}
    palm_top = min(p[n][1] for n in p if n.startswith("palm."))
    for f in ("index", "middle", "ring", "little"):
        assert p[f"{f}.proximal"][3] <= palm_top, f  # fingers above the palm
        assert top[f] < p[f"{f}.middle"][1] < p[f"{f}.proximal"][1], f  # distal at the top
    assert top["middle"] == min(top.values())  # middle finger longest
    assert top["thumb"] > max(v for k, v in top.items() if k != "thumb")  # thumb lower than the fingertips
    assert p["thumb.distal"][0] >= p["index.distal"][2]  # thumb right of index (radial = right)
    assert p["little.distal"][2] <= p["ring.distal"][0]  # little leftmost
    xs = [p[f"{f}.distal"][0] for f in ("little", "ring", "middle", "index", "thumb")]
    assert xs == sorted(xs)
    assert p["thumb.proximal"][3] > palm_top  # thumb reaches down beside the palm
    assert p["palm.upper_ulnar"][0] < p["palm.upper_radial"][0]


def test_canonical_rejects_overlap():
    doc = copy.deepcopy(load_canonical().to_dict())
    doc["places"]["index.middle"]["rect"] = list(doc["places"]["index.distal"]["rect"])
    with pytest.raises(ValueError, match="overlap"):
        parse_canonical(doc, "broken.json")


# --------------------------------------------------------------------------- shipped layouts


def test_list_layouts():
    assert list_layouts() == SHIPPED


def test_opentouch_facts():
    lay = load_layout("opentouch_right_16x16")
    assert lay.hand == "right" and lay.grid == (16, 16)
    assert lay.value == {"convention": "inverted", "max": 3072, "step": 1}
    assert lay.num_live == 169 and 256 - lay.num_live == 87
    assert {b.name: _block_live_count(lay, b) for b in lay.blocks} == OPENTOUCH_REGION_COUNTS
    assert len(lay.bend_cells) == 0 and lay.bend_cells.shape == (0, 2)
    assert all(not b.flip_x and not b.flip_y for b in lay.blocks)
    by = {b.name: b for b in lay.blocks}
    assert by["t2"].place == "thumb.distal" and by["t1"].place == "thumb.proximal"
    assert by["pa4"].place == "palm.upper_ulnar" and by["pa2"].place == "palm.lower_radial"
    assert by["i3"].place == "index.distal" and by["i3"].rows == (0, 2) and by["i3"].cols == (9, 10)
    # a few erased cells from the reference list
    for r, c in [(0, 2), (0, 15), (9, 11), (5, 8)]:
        assert not lay.live_mask[r, c]


def test_touchanything_left_facts():
    lay = load_layout("touchanything_left_21x21")
    assert lay.hand == "left" and lay.grid == (21, 21)
    assert lay.value == {"convention": "direct", "max": 1.0, "step": 1 / 255}
    assert len(lay.bend_cells) == 66
    assert lay.num_live == 151
    assert lay.num_live + len(lay.bend_cells) == 217
    by = {b.name: b for b in lay.blocks}
    for name, (rows, cols) in TA_LEFT_PRESSURE.items():
        assert by[name].rows == rows and by[name].cols == cols and _block_live_count(lay, by[name]) == 12
    palm = by["palm"]
    assert palm.place == "palm" and palm.rows == (13, 17) and palm.cols == (1, 19)
    assert _block_live_count(lay, palm) == 15 + 4 * 19 == 91
    assert sorted(map(tuple, lay.dead_cells.tolist())) == [(13, 16), (13, 17), (13, 18), (13, 19)]
    assert all(not b.flip_x for b in lay.blocks)  # thumb already at high columns = canonical right
    assert not lay.live_mask[lay.bend_cells[:, 0], lay.bend_cells[:, 1]].any()


def test_touchanything_right_is_mirror_of_left():
    left = load_layout("touchanything_left_21x21")
    right = load_layout("touchanything_right_21x21")
    assert right.hand == "right"
    assert np.array_equal(right.live_mask, left.live_mask[:, ::-1])
    assert np.array_equal(right.bend_cells, np.stack([left.bend_cells[:, 0], 20 - left.bend_cells[:, 1]], 1))
    for bl, br in zip(left.blocks, right.blocks):
        assert br.place == bl.place and br.rows == bl.rows
        assert br.cols == (20 - bl.cols[1], 20 - bl.cols[0]) and br.flip_x == (not bl.flip_x)


def test_to_dict_roundtrip(tmp_path):
    for lid in SHIPPED:
        lay = load_layout(lid)
        p = tmp_path / "copy.json"
        p.write_text(json.dumps(lay.to_dict()))
        again = load_layout(p)
        assert again.to_dict() == lay.to_dict()
        assert np.array_equal(again.live_mask, lay.live_mask)


# --------------------------------------------------------------------------- validation


def _doc(lid="opentouch_right_16x16") -> dict:
    return copy.deepcopy(load_layout(lid).to_dict())


def test_rejects_overlapping_blocks():
    doc = _doc()
    doc["blocks"][1]["rows"] = [1, 4]  # p2 (rows 3-5) grows into p3 (rows 0-2)
    with pytest.raises(ValueError, match=r"my_glove\.json: block 'p2'.*overlaps block 'p3'"):
        parse_layout(doc, "my_glove.json")


def test_rejects_out_of_grid_block():
    doc = _doc()
    doc["blocks"][-1]["cols"] = [13, 16]
    with pytest.raises(ValueError, match=r"block 't2'.*outside the 16x16 grid"):
        parse_layout(doc, "my_glove.json")


def test_a_press_level_must_lie_below_full_scale():
    doc = _doc()
    doc["value"]["press"] = doc["value"]["max"]
    with pytest.raises(ValueError, match=r"my_glove\.json: value\.press .* must be below value\.max"):
        parse_layout(doc, "my_glove.json")
    doc["value"]["press"] = 0
    with pytest.raises(ValueError, match=r"my_glove\.json: value/press"):
        parse_layout(doc, "my_glove.json")
    doc["value"]["press"] = 7.5
    assert parse_layout(doc, "my_glove.json").value["press"] == 7.5


def test_rejects_schema_violations():
    doc = _doc()
    doc["value"]["convention"] = "sideways"
    with pytest.raises(ValueError, match=r"my_glove\.json: value/convention"):
        parse_layout(doc, "my_glove.json")
    doc = _doc()
    doc["blocks"][0]["flipx"] = True  # typo in a field name
    with pytest.raises(ValueError, match="blocks/0"):
        parse_layout(doc, "my_glove.json")


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["blocks"][0].update(place="index.tip"), r"block 'p3'.*unknown place 'index.tip'"),
    (lambda d: d["blocks"][0].update(rows=[2, 0]), r"block 'p3'.*first <= last"),
    (lambda d: d["blocks"][1].update(place="little.distal"), r"block 'p2'.*target 'little.distal' overlaps"),
    (lambda d: d["blocks"][1].update(name="p3"), r"block 'p3': duplicate"),
    (lambda d: d.update(dead_cells=[[0, 2]]), r"dead cell \[0, 2\] is not inside any block"),
    (lambda d: d.update(bend_cells=[[0, 0]]), r"bend cell \[0, 0\] is a live pressure cell of block 'p3'"),
    (lambda d: d.update(bend_cells=[[16, 0]]), r"bend_cells cell \[16, 0\] is outside"),
    (lambda d: d.update(dead_cells=[[0, 0], [0, 1], [1, 0], [1, 1], [2, 0], [2, 1]]), r"block 'p3' has no live cell"),
])
def test_rejects_bad_geometry(mutate, message):
    doc = _doc()
    mutate(doc)
    with pytest.raises(ValueError, match=message):
        parse_layout(doc, "my_glove.json")


def test_rejects_group_and_place_on_same_pixels():
    doc = _doc("touchanything_left_21x21")
    doc["blocks"].append({"name": "extra", "place": "palm.upper_ulnar", "rows": [19, 20], "cols": [0, 1]})
    with pytest.raises(ValueError, match=r"block 'extra'.*overlaps target 'palm'"):
        parse_layout(doc, "x.json")


def test_rejects_block_larger_than_place():
    doc = {"layout_id": "dense", "hand": "right", "grid": [64, 64], "value": {"convention": "direct", "max": 1.0},
           "blocks": [{"name": "tip", "place": "little.distal", "rows": [0, 63], "cols": [0, 63]}],
           "dead_cells": [], "bend_cells": [], "source": "test"}
    with pytest.raises(ValueError, match=r"block 'tip': 64x64 cells do not fit"):
        parse_layout(doc, "dense.json")


def test_load_layout_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no_such_glove"):
        load_layout("no_such_glove")
    wrong_id = tmp_path / "dir" / "named_a.json"
    wrong_id.parent.mkdir()
    wrong_id.write_text(json.dumps(_doc("opentouch_right_16x16")))
    with pytest.raises(ValueError, match=r"must equal the file name \('named_a'\)"):
        load_layout("named_a", [wrong_id.parent])
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        load_layout(bad)


# --------------------------------------------------------------------------- CLI


def test_cli_list_check_render(tmp_path, capsys):
    from htdata.cli import main

    assert main(["layouts"]) == 0
    out = capsys.readouterr().out
    for lid in SHIPPED:
        assert lid in out
    print(out)

    good = tmp_path / "my_glove.json"
    doc = _doc("touchanything_left_21x21")
    doc["layout_id"] = "my_glove"
    good.write_text(json.dumps(doc))
    assert main(["layouts", "check", str(good)]) == 0
    assert "OK" in capsys.readouterr().out

    doc["blocks"][0]["cols"] = [1, 5]  # little tip grows into ring tip
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(doc))
    assert main(["layouts", "check", str(broken)]) == 1
    assert "block 'little_tip'" in capsys.readouterr().err

    import cv2

    png = tmp_path / "ot.png"
    assert main(["layouts", "render", "opentouch_right_16x16", str(png)]) == 0
    img = cv2.imread(str(png))
    from htdata.commands.layouts import RENDER_BAND
    assert img is not None and img.shape[0] == RENDER_BAND + 2 * CANVAS and img.shape[1] > 2 * CANVAS


def test_render_draws_its_legend_beside_the_blocks_never_over_them(tmp_path):
    import cv2

    from htdata.commands.layouts import RENDER_BAND, layout_panels, render_layout_png

    for lid in ("opentouch_right_16x16", "touchanything_left_21x21"):
        layout = load_layout(lid)
        png = tmp_path / f"{lid}.png"
        render_layout_png(layout, png)
        img = cv2.imread(str(png))
        # the panels are exactly what layout_panels draws (no text on them); the title and legend are in the band
        assert np.array_equal(img[RENDER_BAND:], layout_panels(layout))
        assert (img[:RENDER_BAND] > 200).all(axis=2).sum() > 200


def test_docs_example_layout_is_valid():
    """The example in docs/LAYOUTS.md is a working layout (docs stay true)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "LAYOUTS.md").read_text()
    doc = json.loads(re.search(r"```json\n(.*?)```", text, re.S).group(1))
    lay = parse_layout(doc, "LAYOUTS.md example")
    assert lay.num_live == 9 + 4 * 12 - 1 and len(lay.bend_cells) == 2


# --------------------------------------------------------------------------- search path + cache


def _write_layout(folder, layout_id, like="opentouch_right_16x16"):
    folder.mkdir(parents=True, exist_ok=True)
    doc = _doc(like)
    doc["layout_id"] = layout_id
    path = folder / f"{layout_id}.json"
    path.write_text(json.dumps(doc))
    return path


def test_search_path_order_dirs_then_env_then_shipped(tmp_path, monkeypatch):
    a = _write_layout(tmp_path / "a", "glove_x")
    b = _write_layout(tmp_path / "b", "glove_x", like="touchanything_left_21x21")
    _write_layout(tmp_path / "b", "glove_y")
    monkeypatch.setenv(LAYOUTS_ENV, f"{tmp_path / 'b'}")
    assert load_layout("glove_x").path == str(b)                  # env only
    assert load_layout("glove_x", [tmp_path / "a"]).path == str(a)  # --layouts DIR comes first
    assert load_layout("glove_y", [tmp_path / "a"]).grid == (16, 16)
    assert {"glove_x", "glove_y", *SHIPPED} <= set(list_layouts([tmp_path / "a"]))
    assert load_layout("opentouch_right_16x16", [tmp_path / "a"]).layout_id == "opentouch_right_16x16"
    # a path is taken relative to `base` (a pipeline file's or a recording's folder)
    assert load_layout("a/glove_x.json", base=tmp_path).path == str(a)


def test_missing_layout_is_one_line_naming_places_and_layouts(tmp_path, monkeypatch):
    _write_layout(tmp_path / "mine", "glove_z")
    monkeypatch.setenv(LAYOUTS_ENV, str(tmp_path / "mine"))
    with pytest.raises(FileNotFoundError) as err:
        load_layout("no_such_glove", [tmp_path / "extra"])
    msg = str(err.value)
    assert "\n" not in msg and "no_such_glove" in msg
    for where in (str(tmp_path / "extra"), str(tmp_path / "mine"), str(L.LAYOUTS_DIR)):
        assert where in msg
    assert "glove_z" in msg and "opentouch_right_16x16" in msg


def test_layout_parsed_once_per_file_version(tmp_path, monkeypatch):
    path = _write_layout(tmp_path, "my_glove")
    calls = []
    real = L.parse_layout
    monkeypatch.setattr(L, "parse_layout", lambda doc, where: calls.append(where) or real(doc, where))
    L._load_layout_file.cache_clear()
    assert load_layout(path) is load_layout(str(path))
    assert load_layout("my_glove", [tmp_path]).path == str(path) and len(calls) == 1
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))   # the file changed: parsed again
    assert load_layout(path).grid == (16, 16) and len(calls) == 2


def test_cli_missing_layout_is_one_line(tmp_path, capsys):
    from htdata.cli import main

    assert main(["layouts", "--layouts", str(tmp_path), "render", "no_such_glove", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no_such_glove" in err and str(tmp_path) in err
    assert "opentouch_right_16x16" in err and "Traceback" not in err


def test_cli_lists_user_layouts(tmp_path, capsys):
    from htdata.cli import main

    _write_layout(tmp_path, "my_glove_32")
    assert main(["layouts", "--layouts", str(tmp_path)]) == 0
    assert "my_glove_32" in capsys.readouterr().out


def test_bend_and_dead_cells_are_optional_and_empty_by_default():
    doc = _doc("opentouch_right_16x16")
    doc["dead_cells"], doc["bend_cells"] = [], []
    full = parse_layout(doc, "full.json")
    lean = {k: v for k, v in doc.items() if k not in ("dead_cells", "bend_cells")}
    bare = parse_layout(lean, "lean.json")
    assert bare.dead_cells.shape == (0, 2) and bare.bend_cells.shape == (0, 2)
    assert np.array_equal(bare.live_mask, full.live_mask)
    # the fields the schema still requires are named when missing
    for field in ("source", "blocks", "value"):
        with pytest.raises(ValueError, match=field):
            parse_layout({k: v for k, v in lean.items() if k != field}, "x.json")
