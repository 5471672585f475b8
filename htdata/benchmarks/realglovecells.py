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
  user passes several recordings): blocks, and the cell precision / recall of
  the suggested layout's live cells against the layout's live cells;
  `suggest_leave_one_out_rows` repeats it with each clip left out in turn.

    python -m htdata.benchmarks.realglovecells ../shared/real_glove
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from htdata.benchmarks.tables import table
from htdata.glove.activity import CellActivity, unmapped_moving
from htdata.glove.layouts import Layout, parse_layout
from htdata.glove.layoutsuggest import suggest_layout

TRUTH_RANGE = 20.0      # counts: a flagged cell that moves more than this in the clip really moves
QUIET_RANGE = 10.0      # counts: a cell ranging less than this must never be flagged
SHORT_FRAMES = 300      # a short clip (135-300 frames: little rest wander to see)
HANDS = ("left", "right")


def load_clips(folder: Path) -> list[tuple[int, np.ndarray]]:
    """(clip id, (T, 2, H, W) float32 raw counts) for every clip of the manifest, in manifest order."""
    out = []
    for line in (folder / "clips" / "manifest.jsonl").read_text().splitlines():
        if line.strip():
            entry = json.loads(line)
            with np.load(folder / "clips" / entry["file"]) as z:
                out.append((int(entry["clip"]), z["counts"].astype(np.float32)))
    return out


def real_layout(folder: Path, hand: str, unused: bool = True) -> Layout:
    """The folder's layout of `hand` (the one json in layouts/ naming it), without `unused_cells` when not `unused`."""
    for path in sorted((folder / "layouts").glob("*.json")):
        doc = json.loads(path.read_text())
        if doc.get("hand") == hand:
            if not unused:
                doc.pop("unused_cells", None)
            return parse_layout(doc, str(path))
    raise FileNotFoundError(f"no {hand}-hand layout in {folder / 'layouts'}")


def _activity(rows: np.ndarray) -> CellActivity:
    act = CellActivity(rows.shape[1:])
    act.add(rows)
    return act


def _share(hit: int, total: int) -> float | str:
    return hit / total if total else "n/a"


def moving_cell_rows(folder: Path, clips: list[tuple[int, np.ndarray]] | None = None) -> list[dict]:
    """One row per (hand, clips): flags of `layouts check --against` and their precision (module docstring)."""
    clips = load_clips(folder) if clips is None else clips
    rows = []
    for h, hand in enumerate(HANDS):
        layout = real_layout(folder, hand, unused=False)
        per_clip = []
        for clip, counts in clips:
            act = _activity(counts[:, h])
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


def suggest_rows(folder: Path, clips: list[tuple[int, np.ndarray]] | None = None) -> list[dict]:
    """One row per (hand, clips): `layouts suggest` from those clips against the layout's live cells."""
    clips = load_clips(folder) if clips is None else clips
    rows = []
    for h, hand in enumerate(HANDS):
        truth = real_layout(folder, hand).live_mask
        for name, chosen in (("all", clips), ("short", [c for c in clips if len(c[1]) <= SHORT_FRAMES])):
            if not chosen:
                continue
            acts = [_activity(counts[:, h]) for _, counts in chosen]
            doc, summary = suggest_layout(acts, hand, f"suggested_{hand}", False, [f"clip_{c}" for c, _ in chosen])
            got = parse_layout(doc, "suggested").live_mask
            tp = int((got & truth).sum())
            rows.append({"hand": hand, "clips": f"{name} ({len(chosen)})", "blocks": len(doc["blocks"]),
                         "precision": _share(tp, int(got.sum())), "recall": _share(tp, int(truth.sum())),
                         "live": int(got.sum()), "true_live": int(truth.sum()),
                         "left_out": len(summary["left_out"]),
                         "boxes": [(b["rows"][0], b["rows"][1], b["cols"][0], b["cols"][1]) for b in doc["blocks"]]})
    return rows


def suggest_leave_one_out_rows(folder: Path, clips: list[tuple[int, np.ndarray]] | None = None) -> list[dict]:
    """One row per hand: `layouts suggest` from every clip but one, for each clip left out (how the targets
    hold on a set of clips it was not developed on): least / median / largest blocks, precision and recall."""
    clips = load_clips(folder) if clips is None else clips
    rows = []
    for h, hand in enumerate(HANDS):
        truth = real_layout(folder, hand).live_mask
        acts = [_activity(counts[:, h]) for _, counts in clips]
        got = {"blocks": [], "precision": [], "recall": []}
        for k in range(len(clips)):
            keep = [a for i, a in enumerate(acts) if i != k]
            doc, _ = suggest_layout(keep, hand, f"suggested_{hand}", False, [f"clip_{c}" for i, (c, _) in
                                                                           enumerate(clips) if i != k])
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


def report(folder: Path) -> list[str]:
    """Markdown lines: both tables."""
    clips = load_clips(folder)
    lines = ["Moving cells (`layouts check --against`, layout without unused_cells): flags = forgotten sensors "
             f"(precision: range > {TRUTH_RANGE:g} counts), cross-talk = cells that only fall below rest", ""]
    lines += table(moving_cell_rows(folder, clips), [
        ("hand", "hand"), ("clips", "clips"), ("flagged", "flagged"), ("precision", "precision"),
        ("under_quiet", f"flags < {QUIET_RANGE:g} counts"), ("crosstalk", "cross-talk"),
        ("crosstalk_precision", "cross-talk precision"), ("threshold_min", "least threshold")])
    lines += ["Suggested blocks (`layouts suggest` from the clips of a hand) against the layout's live cells", ""]
    lines += table(suggest_rows(folder, clips), [
        ("hand", "hand"), ("clips", "clips"), ("blocks", "blocks"), ("precision", "cell precision"),
        ("recall", "cell recall"), ("live", "live cells"), ("true_live", "true live"), ("left_out", "moving left out")])
    lines += ["The same with one clip left out, each in turn (least / median / largest)", ""]
    lines += table(suggest_leave_one_out_rows(folder, clips), [
        ("hand", "hand"), ("subsets", "subsets"), ("blocks_min", "blocks min"), ("blocks_max", "blocks max"),
        ("precision_min", "precision min"), ("precision_median", "precision median"),
        ("recall_min", "recall min"), ("recall_median", "recall median"), ("recall_max", "recall max"),
        ("meet_targets", "subsets meeting all targets")])
    return lines


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m htdata.benchmarks.realglovecells REAL_GLOVE_FOLDER")
    print("\n".join(report(Path(sys.argv[1]))))
