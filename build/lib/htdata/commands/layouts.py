"""`htdata layouts`: list, check and render glove layouts (register a glove: docs/LAYOUTS.md).

    htdata layouts                          # every layout on the search path
    htdata layouts --layouts DIR            # ... including the layouts in DIR
    htdata layouts check my_glove.json      # validate a file, print its coverage
    htdata layouts render opentouch_right_16x16 out.png

Layout ids are searched in --layouts DIR (repeatable), then $HTDATA_LAYOUTS,
then the shipped schemas/layouts/ (htdata.layouts.layout_dirs).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from htdata.format import CANVAS
from htdata.layouts import LAYOUTS_ENV, Layout, list_layouts, load_canonical, load_layout
from htdata.rasterise import Rasteriser

# BGR colours per part id (0 = background), for `htdata layouts render`.
_PART_BGR = np.array([[0, 0, 0], [60, 60, 230], [60, 200, 60], [230, 140, 40], [200, 60, 200],
                      [40, 200, 230], [150, 150, 150]], np.uint8)


def render_layout_png(layout: Layout, out: Path, scale: int = 2) -> None:
    """Two panels: the canonical regions coloured by part, and this glove's coverage."""
    import cv2

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
    r = Rasteriser(layout)
    return {"layout_id": layout.layout_id, "hand": layout.hand, "grid": f"{layout.grid[0]}x{layout.grid[1]}",
            "live": layout.num_live, "bend": len(layout.bend_cells), "blocks": len(layout.blocks),
            "coverage": r.coverage_fraction}


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = "Examples:\n" + __doc__.split("\n\n")[1]
    parser.add_argument("--layouts", action="append", default=[], metavar="DIR",
                        help=f"also search DIR for layout ids (repeatable; before ${LAYOUTS_ENV} and the "
                             "shipped layouts)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.add_parser("list", help="list the layouts on the search path (default)")
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
    dirs = tuple(args.layouts)
    try:
        if action == "list":
            rows = [describe(load_layout(i, dirs)) for i in list_layouts(dirs)]
            _print_rows(rows)
            print("coverage = fraction of the canonical hand's pixels this glove has a sensor under")
        elif action == "check":
            _print_rows([describe(load_layout(Path(args.file)))])
            print(f"OK: {args.file}")
        elif action == "render":
            render_layout_png(load_layout(args.layout, dirs), Path(args.out))
            print(f"wrote {args.out}")
    except (ValueError, OSError) as e:   # OSError covers LayoutNotFound (a FileNotFoundError)
        print(f"htdata layouts: error: {e}", file=sys.stderr)
        return 1
    return 0
