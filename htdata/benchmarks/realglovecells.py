"""Moving cells and suggested blocks on REAL raw-count glove recordings (the README measures of a real_glove folder).

The folder (given explicitly; the toolkit never looks for it) holds
`clips/manifest.jsonl` + `clips/clip_N.npz` (key `counts`, (T, 2, H, W) raw
counts, hand 0 = left) and `layouts/<id>.json` per hand. Per hand, over all
clips and over the short ones (SHORT_FRAMES frames or fewer) separately:

- `moving_cell_rows`: what `htdata layouts check LAYOUT --against` reports
  against the hand's layout WITHOUT its `unused_cells` (the same
  `unmapped_moving` on each clip's raw rows): cells flagged as forgotten
  sensors, their precision (share whose range in that clip > TRUTH_RANGE
  counts), how many flags range < QUIET_RANGE counts (must be none), and the
  cells reported as cross-talk (they only fall below rest) with the same
  precision;
- `suggest_rows`: `htdata layouts suggest` from the clips of one hand (as a
  user passes several recordings; all, the short ones, the pour clips):
  blocks, the cell precision / recall of the suggested layout's live cells
  against the layout's live cells, the README's recall (of the live cells
  pressed, version-2 truth, in >= 2 of the clips given), the regions it
  names as uncovered and the share of the live cells it missed inside them;
  `suggest_leave_one_out_rows` repeats it with each clip left out in turn;
- `crosstalk_rows`: the taxels `htdata stats --health` calls cross-talk
  (htdata/glove/rawhealth.py on each clip's raw rows, as stats runs it per
  episode), on the real glove and each glove derived from it, and their
  precision: a flag is TRUE cross-talk when, in most of the frames the taxel
  is pressed (the README's version-2 truth, original counts), no taxel of
  its own block within STRIP_REACH lines beside its line is pressed (a press
  along the edge of a finger strip lights the edge line with the strip's
  other lines pressed beside it: not cross-talk).

    python -m htdata.benchmarks.realglovecells ../shared/real_glove
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from htdata.benchmarks.realclips import HANDS, RealClip, load_real_glove
from htdata.benchmarks.realglovev2 import DERIVED_GLOVES, GloveTruth, derived_clips, glove_truths
from htdata.benchmarks.tables import table
from htdata.glove.activity import CellActivity, unmapped_moving
from htdata.glove.layouts import Layout, parse_layout
from htdata.glove.layoutsuggest import suggest_layout
from htdata.glove.rawhealth import classify_raw

TRUTH_RANGE = 20.0      # counts: a flagged cell that moves more than this in the clip really moves
QUIET_RANGE = 10.0      # counts: a cell ranging less than this must never be flagged
SHORT_FRAMES = 300      # a short clip (135-300 frames: little rest wander to see)
PRESSED_IN_CLIP = 3     # frames: a live cell pressed in so many frames of a clip was pressed in it (README's forgotten sensor)
STRIP_REACH = 3         # lines beside a cross-talk flag's line that must not be pressed: a 4-line strip from its edge


def bare_layout(layout: Layout) -> Layout:
    """`layout` without its `unused_cells` (what `layouts check` is measured against: every cell outside the
    blocks watched)."""
    doc = layout.to_dict()
    doc.pop("unused_cells", None)
    return parse_layout(doc, f"{layout.layout_id} without unused_cells")


def _activity(rows: np.ndarray) -> CellActivity:
    act = CellActivity(rows.shape[1:])
    act.add(rows)
    return act


def _share(hit: int, total: int) -> float | str:
    return hit / total if total else "n/a"


def moving_cell_rows(clips: list[RealClip], layouts: dict[str, Layout]) -> list[dict]:
    """One row per (hand, clips): flags of `layouts check --against` and their precision (module docstring)."""
    rows = []
    for hand in HANDS:
        layout = bare_layout(layouts[hand])
        per_clip = []
        for c in clips:
            clip, counts = c.clip, c.counts
            act = _activity(c.hand(hand))
            found = unmapped_moving(act, layout)
            rng = act.range
            flagged, crosstalk = rng[tuple(found.cells.T)], rng[tuple(found.crosstalk.T)]
            per_clip.append({"clip": clip, "frames": len(counts), "threshold": found.threshold,
                             "flagged": len(flagged), "true": int((flagged > TRUTH_RANGE).sum()),
                             "under_quiet": int((np.concatenate([flagged, crosstalk]) < QUIET_RANGE).sum()),
                             "crosstalk": len(crosstalk), "crosstalk_true": int((crosstalk > TRUTH_RANGE).sum())})
        for name, keep in (("all", lambda c: True), ("short", lambda c: c["frames"] <= SHORT_FRAMES)):
            chosen = [c for c in per_clip if keep(c)]
            total = {k: sum(c[k] for c in chosen) for k in ("flagged", "true", "under_quiet", "crosstalk",
                                                             "crosstalk_true")}
            rows.append({"hand": hand, "clips": f"{name} ({len(chosen)})", **total,
                         "precision": _share(total["true"], total["flagged"]),
                         "crosstalk_precision": _share(total["crosstalk_true"], total["crosstalk"]),
                         "threshold_min": min((c["threshold"] for c in chosen), default=None),
                         "per_clip": chosen})
    return rows


def pressed_in_clips(truths: dict[int, GloveTruth], chosen: list[RealClip], live: np.ndarray) -> np.ndarray:
    """(H, W) in how many of `chosen` clips each live cell is pressed (version-2 truth) in PRESSED_IN_CLIP frames."""
    out = np.zeros(live.shape, np.int64)
    out[live] = sum((truths[c.clip].pressed.sum(axis=0) >= PRESSED_IN_CLIP).astype(np.int64) for c in chosen)
    return out


def suggest_rows(clips: list[RealClip], layouts: dict[str, Layout]) -> list[dict]:
    """One row per (hand, clips): `layouts suggest` from those clips against the layout's live cells, the README's
    recall (of the live cells pressed in >= 2 of the clips given), and how many of the live cells it missed lie
    in the regions it names as uncovered."""
    rows = []
    for hand in HANDS:
        truth = layouts[hand].live_mask
        truths = glove_truths(clips, hand, truth)
        for name, chosen in (("all", clips), ("short", [c for c in clips if len(c.counts) <= SHORT_FRAMES]),
                             ("pour", [c for c in clips if c.label.startswith("Pour")])):
            if not chosen:
                continue
            acts = [_activity(c.hand(hand)) for c in chosen]
            doc, summary = suggest_layout(acts, hand, f"suggested_{hand}", False, [f"clip_{c.clip}" for c in chosen])
            got = parse_layout(doc, "suggested").live_mask
            tp = int((got & truth).sum())
            pressed = pressed_in_clips(truths, chosen, truth) >= 2
            named = np.zeros(truth.shape, bool)
            for r0, r1, c0, c1 in summary["uncovered"]:
                named[r0:r1 + 1, c0:c1 + 1] = True
            missed = truth & ~got
            rows.append({"hand": hand, "clips": f"{name} ({len(chosen)})", "blocks": len(doc["blocks"]),
                         "precision": _share(tp, int(got.sum())), "recall": _share(tp, int(truth.sum())),
                         "recall_pressed": _share(int((got & pressed).sum()), int(pressed.sum())),
                         "live": int(got.sum()), "true_live": int(truth.sum()), "pressed_live": int(pressed.sum()),
                         "left_out": len(summary["left_out"]), "uncovered_regions": len(summary["uncovered"]),
                         "missed_named": _share(int((missed & named).sum()), int(missed.sum())),
                         "convention": doc["value"]["convention"],
                         "boxes": [(b["rows"][0], b["rows"][1], b["cols"][0], b["cols"][1]) for b in doc["blocks"]]})
    return rows


def suggest_glove_rows(clips: list[RealClip], layouts: dict[str, Layout]) -> list[dict]:
    """One row per (derived glove, hand): `layouts suggest` from all its clips, with the same truth (the original
    presses), and the direction it wrote against the glove's (value.convention)."""
    rows = []
    for glove in DERIVED_GLOVES[1:]:
        g_clips, g_layouts = derived_clips(glove, clips, layouts)
        for hand in HANDS:
            truth = layouts[hand].live_mask
            pressed = pressed_in_clips(glove_truths(clips, hand, truth), clips, truth) >= 2
            doc, _ = suggest_layout([_activity(c.hand(hand)) for c in g_clips], hand, f"suggested_{hand}", False,
                                    [f"clip_{c.clip}" for c in g_clips])
            got = parse_layout(doc, "suggested").live_mask
            rows.append({"glove": glove[0], "hand": hand, "blocks": len(doc["blocks"]),
                         "precision": _share(int((got & truth).sum()), int(got.sum())),
                         "recall_pressed": _share(int((got & pressed).sum()), int(pressed.sum())),
                         "convention": doc["value"]["convention"],
                         "convention_right": doc["value"]["convention"] == g_layouts[hand].value["convention"]})
    return rows


def suggest_leave_one_out_rows(clips: list[RealClip], layouts: dict[str, Layout]) -> list[dict]:
    """One row per hand: `layouts suggest` from every clip but one, for each clip left out (how the targets
    hold on a set of clips it was not developed on): least / median / largest blocks, precision and recall."""
    rows = []
    for hand in HANDS:
        truth = layouts[hand].live_mask
        acts = [_activity(c.hand(hand)) for c in clips]
        got = {"blocks": [], "precision": [], "recall": []}
        for k in range(len(clips)):
            keep = [a for i, a in enumerate(acts) if i != k]
            doc, _ = suggest_layout(keep, hand, f"suggested_{hand}", False,
                                    [f"clip_{c.clip}" for i, c in enumerate(clips) if i != k])
            live = parse_layout(doc, "suggested").live_mask
            tp = int((live & truth).sum())
            got["blocks"].append(len(doc["blocks"]))
            got["precision"].append(tp / max(int(live.sum()), 1))
            got["recall"].append(tp / int(truth.sum()))
        row = {"hand": hand, "subsets": len(clips)}
        for key, values in got.items():
            row.update({f"{key}_min": min(values), f"{key}_median": float(np.median(values)),
                        f"{key}_max": max(values)})
        row["meet_targets"] = sum(b >= 9 and p >= 0.9 and r >= 0.9 for b, p, r in
                                  zip(got["blocks"], got["precision"], got["recall"]))
        rows.append(row)
    return rows


def _line_axis(cell: tuple[int, int], flags: set[tuple[int, int]]) -> int:
    """0 when the flag lies on a raw row with more flagged mates than its column has, else 1."""
    return 0 if sum(f[0] == cell[0] for f in flags) >= sum(f[1] == cell[1] for f in flags) else 1


def _beside(cell: tuple[int, int], axis: int, owner: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Live-cell indices of `cell`'s block off its line, within STRIP_REACH lines across it and one cell along."""
    r, c = cell
    rows, cols = np.nonzero(index >= 0)
    across, along = (rows - r, cols - c) if axis == 0 else (cols - c, rows - r)
    near = (across != 0) & (np.abs(across) <= STRIP_REACH) & (np.abs(along) <= 1) & (owner[rows, cols] == owner[r, c])
    return index[rows[near], cols[near]]


def true_crosstalk(flags: list, truth: GloveTruth, layout: Layout) -> int:
    """How many flagged cells are true cross-talk (module docstring): pressed beside in under half its pressed
    frames (a flag never pressed by the truth only wandered or fell and rose: no press either)."""
    owner = np.full(layout.grid, -1)
    for k, b in enumerate(layout.blocks):
        owner[b.rows[0]:b.rows[1] + 1, b.cols[0]:b.cols[1] + 1] = k
    index = np.full(layout.grid, -1)
    index[layout.live_mask] = np.arange(int(layout.live_mask.sum()))
    cells = {tuple(f) for f in flags}
    hits = 0
    for cell in cells:
        lit = truth.pressed[:, index[cell]]
        beside = _beside(cell, _line_axis(cell, cells), owner, index)
        pressed_beside = truth.pressed[lit][:, beside].any(axis=1) if len(beside) else np.zeros(int(lit.sum()), bool)
        hits += not lit.any() or pressed_beside.mean() < 0.5
    return hits


def crosstalk_rows(clips: list[RealClip], layouts: dict[str, Layout]) -> list[dict]:
    """One row per (glove, hand): the taxel-episodes `stats --health` calls cross-talk and their precision."""
    truths = {h: glove_truths(clips, h, layouts[h].live_mask) for h in HANDS}
    rows = []
    for glove in DERIVED_GLOVES:
        g_clips, g_layouts = derived_clips(glove, clips, layouts) if glove[1] else (clips, layouts)
        for hand in HANDS:
            flagged = hits = 0
            for c in g_clips:
                flags = classify_raw(c.hand(hand), g_layouts[hand])["cells"]["crosstalk"]
                flagged += len(flags)
                hits += true_crosstalk(flags, truths[hand][c.clip], layouts[hand])
            rows.append({"glove": glove[0], "hand": hand, "flagged": flagged, "true": hits,
                         "precision": _share(hits, flagged)})
    return rows


def cells_rows(clips: list[RealClip], layouts: dict[str, Layout], leave_one_out: bool = True) -> dict:
    """Every table's rows (results.json): moving cells, suggest, and suggest with each clip left out."""
    return {"moving_cells": moving_cell_rows(clips, layouts), "suggest": suggest_rows(clips, layouts),
            "suggest_leave_one_out": suggest_leave_one_out_rows(clips, layouts) if leave_one_out else [],
            "suggest_gloves": suggest_glove_rows(clips, layouts),
            "crosstalk": crosstalk_rows(clips, layouts)}


def cells_markdown(d: dict) -> list[str]:
    """Markdown lines: the tables of `cells_rows`."""
    lines = ["Moving cells (`layouts check --against`, layout without unused_cells): flags = forgotten sensors "
             f"(precision: range > {TRUTH_RANGE:g} counts), cross-talk = cells that only fall below rest", ""]
    lines += table(d["moving_cells"], [
        ("hand", "hand"), ("clips", "clips"), ("flagged", "flagged"), ("precision", "precision"),
        ("under_quiet", f"flags < {QUIET_RANGE:g} counts"), ("crosstalk", "cross-talk"),
        ("crosstalk_precision", "cross-talk precision"), ("threshold_min", "least threshold")])
    lines += ["", "Suggested blocks (`layouts suggest` from the clips of a hand) against the layout's live cells", ""]
    lines += table(d["suggest"], [
        ("hand", "hand"), ("clips", "clips"), ("blocks", "blocks"), ("precision", "cell precision"),
        ("recall", "cell recall"), ("recall_pressed", "recall of live cells pressed in >= 2 clips"),
        ("live", "live cells"), ("true_live", "true live"), ("pressed_live", "pressed live"),
        ("left_out", "moving left out"), ("uncovered_regions", "uncovered regions named"),
        ("missed_named", "missed live cells in them"), ("convention", "convention")])
    if d["suggest_leave_one_out"]:
        lines += ["", "The same with one clip left out, each in turn (least / median / largest)", ""]
        lines += table(d["suggest_leave_one_out"], [
            ("hand", "hand"), ("subsets", "subsets"), ("blocks_min", "blocks min"), ("blocks_max", "blocks max"),
            ("precision_min", "precision min"), ("precision_median", "precision median"),
            ("recall_min", "recall min"), ("recall_median", "recall median"), ("recall_max", "recall max"),
            ("meet_targets", "subsets meeting all targets")])
    lines += ["", "The same from all clips of each glove derived from them (truth: the original presses)", ""]
    lines += table(d.get("suggest_gloves", []), [
        ("glove", "glove"), ("hand", "hand"), ("blocks", "blocks"), ("precision", "cell precision"),
        ("recall_pressed", "recall of live cells pressed in >= 2 clips"), ("convention", "convention written"),
        ("convention_right", "the glove's")])
    lines += ["", f"`htdata stats --health` cross-talk flags (taxel-episodes) and their precision: true cross-talk = "
                  f"nothing pressed (version-2 truth) within {STRIP_REACH} lines beside the line in its block "
                  f"(target >= 0.90)", ""]
    lines += table(d.get("crosstalk", []), [("glove", "glove"), ("hand", "hand"), ("flagged", "flagged"),
                                            ("true", "true cross-talk"), ("precision", "precision")])
    return lines


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m htdata.benchmarks.realglovecells REAL_GLOVE_FOLDER")
    print("\n".join(cells_markdown(cells_rows(*load_real_glove(Path(sys.argv[1]))))))
