"""`htdata layouts`: list, check and render glove layouts (register a glove: docs/LAYOUTS.md).

    htdata layouts                          # every layout on the search path
    htdata layouts --layouts DIR            # ... including the layouts in DIR
    htdata layouts check my_glove.json      # validate a file, print its coverage
    htdata layouts check my_glove.json --against /raw/rec_01 /raw/rec_02
                                            # ... and list live cells it leaves out
    htdata layouts suggest /raw/rec_01 my_glove_right.json --hand right
                                            # a starting layout from what moves
    htdata layouts render opentouch_right_16x16 out.png
    htdata layouts rest my_glove_right.json /raw/rec_01 /raw/rec_02 /raw/rec_03 right_rest.npz
                                            # the glove's own rest, for baseline = "shift"

Layout ids are searched in --layouts DIR (repeatable), then $HTDATA_LAYOUTS,
then the shipped schemas/layouts/ (htdata.glove.layouts.layout_dirs).

A RECORDING is a source folder read with --pipeline's adapter (default
native: a recording folder, or a folder of them) or a .npy of raw rows
(T,H,W). A cell MOVES when its range over a recording, the glove's common
wander taken out (htdata.glove.commonmode), exceeds
max(12 x the glove's frame-to-frame noise + 3 x its slow rest wander,
4 x value.step, 0.02 x value.max) (docs/LAYOUTS.md). `check --against`
exits 1 when a cell outside every block (and not in unused_cells /
bend_cells) moves; cells that only fall below their rest are listed as
cross-talk and do not fail the check.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from htdata.commands.outputs import output_path
from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic
from htdata.format.canvas import CANVAS
from htdata.glove.activity import describe_cells, live_moving, rule_text, unmapped_moving
from htdata.glove.glovevalue import CONVENTIONS
from htdata.glove.layouts import LAYOUTS_ENV, Layout, list_layouts, load_canonical, load_layout
from htdata.glove.layoutsuggest import layout_id_from_name, layout_json_text, suggest_layout
from htdata.glove.rasterise import Rasteriser
from htdata.glove.restreference import (
    MIN_RECORDINGS,
    REST_PERCENTILE,
    pooled_reference,
    recording_rest,
    write_rest_reference,
)
from htdata.ingest.recordingscan import scan_recordings

# BGR colours per part id (0 = background), for `htdata layouts render`.
_PART_BGR = np.array([[0, 0, 0], [60, 60, 230], [60, 200, 60], [230, 140, 40], [200, 60, 200],
                      [40, 200, 230], [150, 150, 150]], np.uint8)
_FIRST_ROW = (40, 40, 230)       # BGR red: a block's first raw row
_FIRST_CELL = (0, 230, 255)      # BGR yellow: its first cell


def orientation_grids(layout: Layout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(1,H,W) grids marking each block's orientation: raw-column ramp, first raw row, first cell."""
    ramp = np.zeros((1, *layout.grid), np.float32)
    first_row = np.zeros_like(ramp)
    first_cell = np.zeros_like(ramp)
    for b in layout.blocks:
        n = b.shape[1]
        ramp[0, b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = 0.35 + 0.65 * np.arange(n) / max(n - 1, 1)
        first_row[0, b.rows[0], b.cols[0]:b.cols[1] + 1] = 1.0
        first_cell[0, b.rows[0], b.cols[0]] = 1.0
    return ramp, first_row, first_cell


RENDER_BAND = 44          # px above the panels (at any scale) for the title and the legend: never over a block


def layout_panels(layout: Layout, scale: int = 2) -> np.ndarray:
    """Two panels, no text: the canonical regions coloured by part, and this glove's coverage and block orientation.

    Coverage panel: covered pixels grow brighter along each block's raw columns; the block's first raw
    row is red and its first cell (rows[0], cols[0]) yellow, so transpose/rotate/flips can be checked.
    """
    import cv2

    canon = load_canonical()
    r = Rasteriser(layout, canonical=canon)
    regions = _PART_BGR[canon.part_map].astype(np.float32)
    regions *= np.where(canon.region_map % 2 == 1, 1.0, 0.7)[..., None]  # tell neighbouring regions apart
    cov = np.zeros_like(regions)
    inside = canon.region_map > 0
    cov[inside] = regions[inside] * 0.25
    ramp, first_row, first_cell = (r.render(g)[0] for g in orientation_grids(layout))
    covered = r.coverage == 1
    cov[covered] = (255 * ramp[covered])[:, None]
    cov[covered & (first_row > 0)] = _FIRST_ROW
    cov[covered & (first_cell > 0)] = _FIRST_CELL
    img = np.concatenate([regions, np.full((CANVAS, 4, 3), 255, np.float32), cov], axis=1).astype(np.uint8)
    return cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)


def render_layout_png(layout: Layout, out: Path, scale: int = 2) -> None:
    """`layout_panels` under a band holding the title (id, coverage) and the legend with colour swatches."""
    import cv2

    panels = layout_panels(layout, scale)
    img = np.zeros((RENDER_BAND + panels.shape[0], panels.shape[1], 3), np.uint8)
    img[RENDER_BAND:] = panels
    font, white = cv2.FONT_HERSHEY_SIMPLEX, (255, 255, 255)
    text = f"{layout.layout_id}  coverage {Rasteriser(layout).coverage_fraction:.3f}"
    cv2.putText(img, text, (6, 16), font, 0.45, white, 1, cv2.LINE_AA)
    x = 6
    for colour, words in ((_FIRST_ROW, "first raw row"), (_FIRST_CELL, "first cell"),
                          ((200, 200, 200), "brighter: higher raw column")):
        cv2.rectangle(img, (x, 26), (x + 10, 36), colour, cv2.FILLED)
        cv2.putText(img, words, (x + 14, 36), font, 0.4, white, 1, cv2.LINE_AA)
        x += 14 + cv2.getTextSize(words, font, 0.4, 1)[0][0] + 16
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), img):
        raise OSError(f"could not write {out}")


def describe(layout: Layout) -> dict:
    """Numbers shown by `htdata layouts`: live taxels, bend cells, coverage."""
    r = Rasteriser(layout)
    return {"layout_id": layout.layout_id, "hand": layout.hand, "grid": f"{layout.grid[0]}x{layout.grid[1]}",
            "live": layout.num_live, "bend": len(layout.bend_cells), "blocks": len(layout.blocks),
            "coverage": r.coverage_fraction}


def check_against(layout: Layout, recordings: list[str], pipeline: str) -> int:
    """Print each recording hand's unmapped moving cells with their activity; 1 when any moves."""
    scanned = scan_recordings(recordings, pipeline, layout.hand, layout.path)
    if not scanned:
        raise ArgumentError(f"no {layout.hand}-hand rows in {', '.join(recordings)} (layout {layout.layout_id} is "
                            f"for the {layout.hand} hand)")
    findings: set[tuple[int, int]] = set()
    pressed = np.zeros(layout.grid, bool)
    for s in scanned:
        if s.activity.grid != tuple(layout.grid):
            raise ArgumentError(f"{s.recording} [{s.episode_id}]: {s.hand} rows are {s.activity.grid[0]}x"
                                f"{s.activity.grid[1]}, layout {layout.layout_id} is {layout.grid[0]}x{layout.grid[1]}")
        pressed[tuple(live_moving(s.activity, layout).cells.T)] = True
        found = unmapped_moving(s.activity, layout)
        head = (f"{s.recording} [{s.episode_id}] {s.hand} hand: {found.frames} frames, noise {found.noise:.4g}, "
                f"wander {found.wander:.4g}, moving = range > {found.threshold:.4g}")
        crosstalk = (f"; {len(found.crosstalk)} only fall below rest (cross-talk beside a press, not a "
                     f"sensor){_ranged(found.crosstalk, found.crosstalk_ranges)}" if len(found.crosstalk) else "")
        if not len(found):
            print(f"{head}: no cell outside the blocks {'rises' if crosstalk else 'moves'}{crosstalk}")
            continue
        findings.update(map(tuple, found.cells.tolist()))
        print(f"{head}: {len(found)} cell(s) outside every block move{crosstalk}:")
        # range: less the glove's common wander (what the rule reads); min / max: the raw values
        print(f"    {'cell':>9s} {'range':>9s} {'raw min':>9s} {'raw max':>9s} {'noise':>8s} {'wander':>8s}")
        wander = s.activity.cell_wander()
        for (r, c), v in zip(found.cells.tolist(), found.ranges):
            print(f"    {f'[{r}, {c}]':>9s} {v:9.4g} {s.activity.lo[r, c]:9.4g} {s.activity.hi[r, c]:9.4g} "
                  f"{s.activity.cell_noise[r, c]:8.3g} {wander[r, c]:8.3g}")
    print(_unpressed_blocks_line(layout, pressed))
    if findings:
        print(f"FINDING: {len(findings)} distinct cell(s) outside every block move in {len(scanned)} recording "
              f"hand(s) and are not drawn: add them to a block, or list them in unused_cells of "
              f"{layout.path or layout.layout_id}")
        return 1
    return 0


def _unpressed_blocks_line(layout: Layout, pressed: np.ndarray) -> str:
    """The blocks none of whose live cells moved in any recording: what the recordings cannot check (not a
    finding: an idle finger is no fault, but its blocks' cells and orientation stay untested)."""
    live = np.asarray(layout.live_mask, bool)
    idle = [f"{b.name} ({b.place}, rows {b.rows[0]}-{b.rows[1]}, cols {b.cols[0]}-{b.cols[1]})" for b in layout.blocks
            if not (pressed & live)[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1].any()]
    if not idle:
        return f"every one of the {len(layout.blocks)} blocks was pressed in some recording"
    return (f"not pressed: {len(idle)} of {len(layout.blocks)} blocks moved in no recording (record presses there to "
            f"check them): {', '.join(idle)}")


def _ranged(cells: np.ndarray, ranges: np.ndarray, limit: int = 12) -> str:
    """": [r, c] range, ..." for the first `limit` cells."""
    return ": " + describe_cells(cells.tolist(), ranges.tolist(), limit) if len(cells) else ""


def _cells(cells: list, limit: int = 12) -> str:
    """": [r, c], ... (N more)" for the first `limit` cells, "" for none."""
    if not cells:
        return ""
    more = f", ... {len(cells) - limit} more" if len(cells) > limit else ""
    return ": " + ", ".join(f"[{r}, {c}]" for r, c in cells[:limit]) + more


def recordings_and_out(args: argparse.Namespace, action: str, suffix: str) -> tuple[list[str], Path]:
    """`RECORDING... OUT` of suggest / rest: at least one recording, OUT with `suffix`, new unless --force."""
    if len(args.paths) < 2:
        raise ArgumentError(f"{action} needs at least one RECORDING and the OUT{suffix} to write")
    *recordings, out = args.paths
    out = Path(out)
    if out.suffix != suffix:
        raise ArgumentError(f"OUT must be a {suffix} file, got {out}")
    if out.exists() and not args.force:
        raise ArgumentError(f"{out} exists (use --force to overwrite it)")
    return recordings, out


def suggest(args: argparse.Namespace) -> int:
    """`htdata layouts suggest RECORDING... OUT.json`."""
    recordings, out = recordings_and_out(args, "suggest", ".json")
    scanned = scan_recordings(recordings, args.pipeline, args.hand)
    hands = sorted({s.hand for s in scanned})
    if not scanned:
        raise ArgumentError(f"no {args.hand or ''} tactile rows in {', '.join(recordings)}".replace("  ", " "))
    if len(hands) > 1:
        raise ArgumentError(f"the recordings hold both hands ({', '.join(hands)}): choose one with --hand")
    layout_id = args.layout_id or layout_id_from_name(out.stem)
    doc, summary = suggest_layout([s.activity for s in scanned], hands[0], layout_id,
                                  all(s.integral for s in scanned), recordings, args.max_value, args.convention)
    write_bytes_atomic(output_path(out, "layouts suggest"), layout_json_text(doc).encode())
    print(f"{summary['moving']} moving cell(s) in {summary['recordings']} recording hand(s), {summary['frames']} "
          f"frames (median noise {summary['noise']:.4g}, wander {summary['wander']:.4g}, moving = range > {summary['threshold']:.4g}); "
          f"{len(doc['blocks'])} block(s), "
          f"{summary['inside_blocks_not_moving']} cell(s) inside them did not move; {len(summary['left_out'])} "
          f"moving cell(s) outside them (lines, lone cells, patches of one recording){_cells(summary['left_out'])}:")
    for b in doc["blocks"]:
        turn = f", rotate {b['rotate']}" if b.get("rotate") else ""
        print(f"    {b['name']:10s} rows {b['rows'][0]}-{b['rows'][1]} cols {b['cols'][0]}-{b['cols'][1]} "
              f"-> {b['place']} (placeholder{turn})")
    print(f"{'WARNING: ' if summary['direction_unclear'] else ''}{summary['direction']}")
    print(f"not seen: {summary['unseen']}")
    print(f"wrote {out}: a STARTING POINT. Set each block's place and orientation, then "
          f"`htdata layouts render {out} out.png` and `htdata layouts check {out} --against "
          f"{' '.join(recordings)}`")
    return 0


def configure_parser(parser: argparse.ArgumentParser) -> None:
    paras = __doc__.split("\n\n")
    parser.epilog = "\n\n".join(paras[2:]) + "\n\nExamples:\n" + paras[1]
    parser.add_argument("--layouts", action="append", default=[], metavar="DIR",
                        help=f"also search DIR for layout ids (repeatable; before ${LAYOUTS_ENV} and the "
                             "shipped layouts)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.add_parser("list", help="list the layouts on the search path (default)")
    p = sub.add_parser("check", help="validate a layout and print its coverage; with --against, list the cells "
                                     "outside every block that move in recordings")
    p.epilog = ("example: htdata layouts check my_glove.json --against /raw/rec_01 /raw/rec_02\n"
                f"A cell moves when its raw {rule_text()} in a recording "
                "(docs/LAYOUTS.md); cells in unused_cells or bend_cells are never listed; cells that only fall "
                "below their rest are listed as cross-talk and do not fail the check.")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("file", metavar="LAYOUT", help="path to a layout JSON (or a layout id)")
    p.add_argument("--against", nargs="+", default=[], metavar="RECORDING",
                   help="recordings to measure (source folders or .npy raw rows); exit 1 when an unmapped cell moves")
    p.add_argument("--pipeline", default="native",
                   help="pipeline whose adapter reads the recordings (default: native)")
    p = sub.add_parser("suggest", help="write a starting layout whose blocks cover the cells that move in recordings")
    p.epilog = ("example: htdata layouts suggest /raw/rec_01 /raw/rec_02 my_glove_right.json --hand right\n"
                "Blocks = the cells that rise in recordings (in two of them when three or more are given), cut "
                "where the shape narrows and along rows / columns that do not move, strips cut into near-square "
                "blocks; places are PLACEHOLDERS by size: edit them, then render and check the layout "
                "(docs/LAYOUTS.md).")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("paths", nargs="+", metavar="RECORDING... OUT.json",
                   help="recordings (source folders or .npy raw rows), then the layout JSON to write")
    p.add_argument("--hand", choices=("left", "right"),
                   help="which hand (required when a recording holds both, or for .npy rows)")
    p.add_argument("--pipeline", default="native",
                   help="pipeline whose adapter reads the recordings (default: native)")
    p.add_argument("--layout-id", help="layout id to write (default: from OUT's file name)")
    p.add_argument("--max", type=float, dest="max_value",
                   help="full-scale raw value for value.max (default: the largest value seen)")
    p.add_argument("--convention", choices=CONVENTIONS,
                   help="the glove's direction for value.convention: counts rise (direct) or fall (inverted) with "
                        "pressure (default: as the recordings show it)")
    p.add_argument("--force", action="store_true", help="overwrite OUT.json")
    p = sub.add_parser("rest", help="write the glove's own rest: each cell's rest pooled over its recordings "
                                    "(a taxel calibration for baseline = \"shift\")")
    p.epilog = (f"example: htdata layouts rest my_glove_right.json /raw/rec_01 /raw/rec_02 /raw/rec_03 rest.npz\n"
                f"A cell's rest in a recording is its {REST_PERCENTILE:g}th percentile on the no-pressure side; the "
                f"reference is the median over the recordings (at least {MIN_RECORDINGS}), so a grip held through "
                "one recording does not move it. Then in the pipeline: [normalise.LAYOUT] taxel_calibration = "
                "\"rest.npz\", baseline = \"shift\", noise_k = 5 (docs/INGEST.md, \"The glove's own rest\").")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("layout", help="the glove hand's layout (id or JSON): its grid, hand and value.convention")
    p.add_argument("paths", nargs="+", metavar="RECORDING... OUT.npz",
                   help="recordings of that glove (source folders or .npy raw rows), then the .npz to write")
    p.add_argument("--pipeline", default="native",
                   help="pipeline whose adapter reads the recordings (default: native)")
    p.add_argument("--force", action="store_true", help="overwrite OUT.npz")
    p = sub.add_parser("render", help="draw the region map + coverage of a layout as a PNG")
    p.add_argument("layout", help="layout id or path to a layout JSON")
    p.add_argument("out", help="output .png path")


def rest(args: argparse.Namespace, dirs: tuple) -> int:
    """`htdata layouts rest LAYOUT RECORDING... OUT.npz`."""
    recordings, out = recordings_and_out(args, "rest", ".npz")
    layout = load_layout(Path(args.layout) if args.layout.endswith(".json") else args.layout, dirs)
    scanned = scan_recordings(recordings, args.pipeline, layout.hand, layout.path, keep_rows=True)
    if not scanned:
        raise ArgumentError(f"no {layout.hand}-hand rows in {', '.join(recordings)} (layout {layout.layout_id})")
    for s in scanned:
        if s.rows.shape[1:] != tuple(layout.grid):
            raise ArgumentError(f"{s.recording} [{s.episode_id}]: {s.hand} rows are {s.rows.shape[1]}x{s.rows.shape[2]}, "
                                f"layout {layout.layout_id} is {layout.grid[0]}x{layout.grid[1]}")
    convention = layout.value["convention"]
    rests = [recording_rest(s.rows, convention) for s in scanned]
    reference = pooled_reference(rests)
    live = np.asarray(layout.live_mask, bool)
    away = np.stack([r - reference for r in rests])[:, live]
    write_rest_reference(output_path(out, "layouts rest"), reference)
    print(f"{len(scanned)} {layout.hand}-hand recording(s) of {layout.layout_id} ({convention}); per recording, "
          f"the median live cell's rest sits {', '.join(f'{float(np.nanmedian(a)):+.3g}' for a in away)} counts "
          f"from the reference (the common-mode shift baseline = \"shift\" fits)")
    print(f"wrote {out}: in the pipeline, [normalise.{layout.layout_id}] taxel_calibration = \"{out.name}\", "
          f"baseline = \"shift\", noise_k = 5")
    return 0


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
            layout = load_layout(Path(args.file) if args.file.endswith(".json") or Path(args.file).exists()
                                 else args.file, dirs)
            _print_rows([describe(layout)])
            print(f"OK: {args.file}")
            if args.against:
                return check_against(layout, args.against, args.pipeline)
        elif action == "suggest":
            return suggest(args)
        elif action == "rest":
            return rest(args, dirs)
        elif action == "render":
            render_layout_png(load_layout(args.layout, dirs), output_path(args.out, "layouts render"))
            print(f"wrote {args.out}")
    except (ValueError, OSError) as e:   # OSError covers LayoutNotFound (a FileNotFoundError)
        print(f"htdata layouts: error: {e}", file=sys.stderr)
        return 1
    return 0
