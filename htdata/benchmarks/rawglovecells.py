"""`make bench` section "raw-count glove", moving cells: the one moving-cell rule scored against the generator's truth.

On the sample raw-count glove (htdata/synthetic/rawglove.py: every cell, taxel
and gap, wanders slowly at rest), each clip and hand is measured against a
FIRST-DRAFT layout that forgets a sensor area (`draft_layout_doc`: the
thumb tip) and declares no unused cells, so the unmapped cells are the gaps
plus that area. Truth "really pressed" = an unmapped cell that carries a
responding sensor pressed by more than the rule's least move (0.02 of full
scale) in the clip; a lighter press beyond quiet (5 counts) counts neither
way (`unmapped_truth`).

- rule rows: the one rule (htdata/glove/activity.py: 12 x fast noise + 3 x
  rest wander, at least 0.02 of full scale) and the rule before issue 27
  (12 x fast noise, 4 steps):
  precision and recall of "moving" against "really pressed", summed over
  clips and hands. The false positives are split into ghosts (the cross-talk
  column, cells falling beside a press) or loud cells (cells that do move,
  not pressed) and the rest
  (resting cells whose slow wander was called movement);
- suggest rows: `htdata layouts suggest`'s blocks from all clips of a hand
  against the true sensor areas (the boxes of the true layout's connected
  live cells: on the rebuilt glove, whose palm touches every finger strip
  and the thumb, one box): blocks suggested,
  true areas, suggested blocks that are exactly a true area, and per cell
  precision / recall of the suggested live cells against the true ones (and
  the recall of the true cells pressed in some clip: suggest can only find
  what was pressed).
"""

from __future__ import annotations

import numpy as np

from htdata.errors import ArgumentError
from htdata.glove.activity import CellActivity, moving_threshold, unmapped_moving
from htdata.glove.layouts import parse_layout
from htdata.glove.layoutsuggest import cell_boxes, suggest_layout
from htdata.synthetic.rawglove import GloveUnit, RawGloveClip, draft_layout_doc, glove_layout, unmapped_truth


def _rates(tp: int, fp: int, fn: int) -> tuple[float | None, float | None]:
    return (tp / (tp + fp) if tp + fp else None), (tp / (tp + fn) if tp + fn else None)


def moving_cell_rows(clips: list[RawGloveClip], units: dict[str, GloveUnit]) -> list[dict]:
    """One row per rule: precision / recall of unmapped moving cells against the truth (module docstring)."""
    counts = {name: {"tp": 0, "fp": 0, "fn": 0, "fp_moving": 0, "fp_rest": 0} for name in ("one rule", "today's rule")}
    for hand, unit in units.items():
        draft = parse_layout(draft_layout_doc(hand), "draft")
        for clip in clips:
            act = CellActivity(draft.grid)
            act.add(clip.counts[hand])
            found = unmapped_moving(act, draft)
            new = np.zeros(draft.grid, bool)
            new[tuple(found.cells.T)] = True
            old = draft.unmapped_mask & (act.range > moving_threshold(found.noise, draft.value.get("step")))
            truth = unmapped_truth(clip, hand, unit, draft)
            moves = truth["ghost"] | truth["loud"]
            for name, hit in (("one rule", new), ("today's rule", old)):
                c = counts[name]
                c["tp"] += int((hit & truth["pressed"]).sum())
                c["fn"] += int((~hit & truth["pressed"]).sum())
                fp = hit & ~(truth["pressed"] | truth["light"])     # a light press found is no false finding
                c["fp"] += int(fp.sum())
                c["fp_moving"] += int((fp & moves).sum())
                c["fp_rest"] += int((fp & ~moves).sum())
    rows = []
    for name, c in counts.items():
        precision, recall = _rates(c["tp"], c["fp"], c["fn"])
        rows.append({"rule": name, "pressed": c["tp"] + c["fn"], "found": c["tp"], "precision": precision,
                     "recall": recall, "false_ghost_or_loud": c["fp_moving"], "false_resting": c["fp_rest"]})
    return rows


def suggest_rows(clips: list[RawGloveClip], units: dict[str, GloveUnit]) -> list[dict]:
    """One row per hand: `layouts suggest` from every clip against the true sensor areas."""
    rows = []
    for hand in units:
        acts = []
        for clip in clips:
            acts.append(CellActivity(glove_layout(hand).grid))
            acts[-1].add(clip.counts[hand])
        try:
            doc, summary = suggest_layout(acts, hand, "suggested", True, [c.name for c in clips])
        except ArgumentError as exc:      # a hand these clips hardly press (a --quick run): said, not a failure
            rows.append({"hand": hand, "blocks": 0, "true_areas": None, "exact_areas": None, "precision": None,
                         "recall": None, "recall_of_pressed": None, "left_out": None, "threshold": None,
                         "no_suggestion": str(exc)})
            continue
        got, true = parse_layout(doc, "suggested").live_mask, glove_layout(hand).live_mask
        pressed = np.zeros(true.shape, bool)
        for clip in clips:
            pressed |= clip.pressure[hand].max(axis=0) >= 0.05
        tp = int((got & true).sum())
        precision, recall = _rates(tp, int((got & ~true).sum()), int((~got & true).sum()))
        areas = set(cell_boxes(true))        # the true sensor areas: a finger's segments make one area
        exact = {(b["rows"][0], b["rows"][1], b["cols"][0], b["cols"][1]) for b in doc["blocks"]} & areas
        rows.append({"hand": hand, "blocks": len(doc["blocks"]), "true_areas": len(areas),
                     "exact_areas": len(exact), "precision": precision, "recall": recall,
                     "recall_of_pressed": int((got & true & pressed).sum()) / max(int((true & pressed).sum()), 1),
                     "left_out": len(summary["left_out"]), "threshold": summary["threshold"]})
    return rows
