"""HT-Bench report: results JSON, markdown tables, a predictions PNG.

results.md opens with the verdicts against the reference predictors (verdicts.py) and, when
the run's meta has them, its checks, held-out gate and misalignment control; then three tables, one row
per model per part:
- the paper's column order with F-/H- metrics over sensor-covered pixels
  (`COLUMNS`; regions f_covered / h_covered);
- the same map metrics over the whole canvas / hidden part (`FULL_COLUMNS`;
  f_full / h_full), the figures comparable with the paper's "full tactile map";
- retrieval next to its chance levels (`RETRIEVAL_COLUMNS`).
RMSE / cIoU cells are per-frame means (pooled values are in the JSON).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from handtouch.bench.verdicts import cell, verdict_table
from htdata.fileio import write_text_atomic

Column = tuple[str, str, "str | None", str]     # (header, track, region, key)

# Map-metric columns in the paper's order; "{}" is the scope, "covered" or "full".
_MAP_COLUMNS: tuple[Column, ...] = (
    ("Inpaint F-RMSE", "inpaint", "f_{}", "rmse"),
    ("F-cIoU", "inpaint", "f_{}", "ciou"),
    ("H-RMSE", "inpaint", "h_{}", "rmse"),
    ("H-cIoU", "inpaint", "h_{}", "ciou"),
    ("RGB2T F-RMSE", "rgb2tactile", "f_{}", "rmse"),
    ("F-cIoU", "rgb2tactile", "f_{}", "ciou"),
    ("Pred F-RMSE", "prediction", "f_{}", "rmse"),
    ("F-cIoU", "prediction", "f_{}", "ciou"),
)


def map_columns(scope: str) -> tuple[Column, ...]:
    """The map-metric columns over one scope: "covered" or "full"."""
    if scope not in ("covered", "full"):
        raise ValueError(f"scope must be 'covered' or 'full', got {scope!r}")
    return tuple((h, t, r.format(scope), k) for h, t, r, k in _MAP_COLUMNS)


# The paper's table: retrieval, then map metrics over covered pixels.
COLUMNS: tuple[Column, ...] = (
    ("Retrieval Hit@1", "retrieval", None, "hit_at_1"),
    ("Retrieval R@5", "retrieval", None, "recall_at_5"),
    *map_columns("covered"),
)
FULL_COLUMNS: tuple[Column, ...] = map_columns("full")
RETRIEVAL_COLUMNS: tuple[Column, ...] = (
    ("Hit@1", "retrieval", None, "hit_at_1"),
    ("Hit@1 constant", "retrieval", None, "constant_hit_at_1"),
    ("Hit@1 shuffled", "retrieval", None, "shuffled_hit_at_1"),
    ("Hit@1 theory", "retrieval", None, "chance_hit_at_1"),
    ("R@5", "retrieval", None, "recall_at_5"),
    ("R@5 constant", "retrieval", None, "constant_recall_at_5"),
    ("R@5 shuffled", "retrieval", None, "shuffled_recall_at_5"),
    ("R@5 theory", "retrieval", None, "chance_recall_at_5"),
)
PANEL_COLUMNS = ("RGB", "GT", "inpaint", "rgb2tactile", "prediction", "|pred-GT|")




def _fmt(v) -> str:
    return "–" if v is None else f"{v:.3f}"


def markdown_table(results: dict[str, dict[str, dict]], columns: tuple[Column, ...] = COLUMNS) -> str:
    """results: {model name: {part: tracks}} -> markdown table, rows 'model (part)'."""
    header = "| Model | " + " | ".join(h for h, *_ in columns) + " |"
    rule = "|---|" + "---:|" * len(columns)
    rows = [header, rule]
    for model, parts in results.items():
        for part, metrics in parts.items():
            vals = [_fmt(cell(metrics, t, r, k)) for _, t, r, k in columns]
            rows.append(f"| {model} ({part}) | " + " | ".join(vals) + " |")
    return "\n".join(rows) + "\n"


def _fmt_any(v) -> str:
    return f"{v:.4f}" if isinstance(v, float) else ("–" if v is None else str(v))


def checks_markdown(checks: list[dict]) -> str:
    """The run's pass/fail checks (meta["checks"]): check, value, limit, verdict."""
    rows = ["| Check | Value | Limit | Verdict |", "|---|---:|---:|---|"]
    rows += [f"| {c['check']} | {_fmt_any(c['value'])} | {_fmt_any(c['limit'])} | "
             f"{'ok' if c['ok'] else ('FAILED' if c.get('required', True) else 'missed (reported, not required)')} |"
             for c in checks]
    return "\n".join(rows) + "\n"


def control_markdown(control: dict) -> str:
    """Misalignment control (meta["misalignment_control"]): the RGB probes' coarse-map MSE
    relative to all zeros per pairing, and the trained model's RGB-to-tactile F-RMSE with the
    frame mis-paired at evaluation time."""
    rows = ["| Part | Pairing | Probe coarse MSE / zeros | Probe items | Model RGB2T F-RMSE | "
            "same items, aligned |", "|---|---|---:|---:|---:|---:|"]
    for part, pairings in control.get("probe", {}).items():
        for pairing, score in pairings.items():
            model = control.get("model", {}).get(part, {}).get(pairing, {})
            rows.append(f"| {part} | {pairing} | {_fmt_any(score.get('ratio'))} | {score.get('items')} | "
                        f"{_fmt_any(model.get('rmse'))} | {_fmt_any(model.get('aligned_rmse'))} |")
    return "\n".join(rows) + "\n"


def _groups(report: dict) -> list[dict]:
    """The held-out gate's groups (test, ood, stress), without its pooled lag curve (report["lag"])."""
    return [g for g in report.values() if "timing" in g]


def heldout_markdown(report: dict) -> str:
    """The held-out gate (meta["heldout_gate"], handtouch.contact_gate): contact-timing AUROC per group
    with its mis-paired control, then F-RMSE per frame / pooled / on contact frames against the better
    of all zeros and the mis-paired model."""
    rows = ["| Frames of | AUROC | mis-paired RGB | phase-matched RGB | clock (no image) | best lag shift "
            "(frames) | streams with contact (idle) | frames (contact) | required |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for g in _groups(report):
        t = g["timing"]
        lag = (g.get("lag") or {}).get("best_shift")
        rows.append(f"| {g['where']} | {_fmt_any(t['auroc'])} | {_fmt_any(t['mispaired_auroc'])} | "
                    f"{_fmt_any(t.get('phase_matched_auroc'))} | {_fmt_any(t.get('position_auroc'))} | "
                    f"{_fmt_any(lag)} | {t['streams']} ({t['idle_streams']}) | {t['frames']} "
                    f"({t['contact_frames']}) | {'yes' if g['required'] else 'reported'} |")
    rmse = ["| Frames of | F-RMSE | model | all zeros | mis-paired RGB | frames | verdict |",
            "|---|---|---:|---:|---:|---:|---|"]
    for g in _groups(report):
        for measure, r in g["rmse"].items():
            word = "ok" if r["ok"] else "not yet"
            rmse.append(f"| {g['where']} | {measure} | {_fmt_any(r['aligned'])} | {_fmt_any(r['zeros'])} | "
                        f"{_fmt_any(r['mispaired'])} | {r['frames']} | {word} (vs {r['against'] or '–'}) |")
    pooled = report.get("lag")
    lag = (f"\nThe lag check pools {pooled['where']}: predicted and measured contact agree best at a shift of "
           f"{pooled['curve']['best_shift']} frames (required within +-2).\n") if pooled else ""
    return "\n".join(rows) + "\n" + lag + "\n" + "\n".join(rmse) + "\n"


def headline_markdown(meta: dict) -> str:
    """The first lines of results.md: passed or not, the held-out gate's figures against their controls,
    and what a "not yet" cell means at the smoke's budget."""
    checks = meta.get("checks") or []
    required = [c for c in checks if c.get("required", True)]
    failed = [c["check"] for c in required if not c["ok"]]
    lines = []
    if checks:
        verdict = "PASSED" if not failed else f"FAILED ({len(failed)} of {len(required)} required checks)"
        if meta.get("broken_control"):
            verdict += (f" -- a broken control run ({meta['broken_control']}): here a failure is the expected "
                        "outcome")
        lines.append(f"**{verdict}**: {len(required) - len(failed)} of {len(required)} required checks ok; "
                     f"{len(checks) - len(required)} more reported only.")
        lines += [f"- failed: {c}" for c in failed]
    gate = (meta.get("heldout_gate") or {}).get("ood")
    if gate:
        pooled = (meta.get("heldout_gate") or {}).get("lag")
        t = gate["timing"]
        lag = (pooled["curve"] if pooled else gate.get("lag") or {}).get("best_shift")
        lines.append(f"- held-out gate on {gate['where']}: contact-timing AUROC {_fmt_any(t['auroc'])} against "
                     f"{_fmt_any(t['mispaired_auroc'])} with another episode's frame at a random moment, "
                     f"{_fmt_any(t.get('phase_matched_auroc'))} at the same moment, and "
                     f"{_fmt_any(t.get('position_auroc'))} for a clock that reads no image; predicted and "
                     f"measured contact agree best at a shift of {_fmt_any(lag)} frames"
                     f"{' (test and held-out streams pooled)' if pooled else ''}.")
    lines.append("- \"not yet\" in the verdict table: the model is measured and not better than that reference "
                 "at this budget (a few hundred steps on CPU). Only the checks below decide the run; at the "
                 "smoke's budget several not-yet cells are expected (docs/HANDTOUCH.md, \"Held-out gate\").")
    return "\n".join(lines) + "\n"


def results_markdown(results: dict[str, dict[str, dict]], meta: dict | None = None) -> str:
    """The results.md document: a headline, verdicts (and the run's checks / misalignment control when
    meta has them), covered-pixel table, whole-canvas table, retrieval chance table."""

    meta = meta or {}
    head = ["# HT-Bench results\n", headline_markdown(meta),
            "RMSE / cIoU: per-frame means; cIoU clamps predictions to [0,1]. Definitions: README, "
            "\"HT-Bench metrics: definitions\".\n",
            "## Verdicts against the references\n",
            "Each trained model against the reference predictors on the same items (covered pixels; "
            "handtouch/bench/verdicts.py): ok = better than the reference, not yet = measured, not better.\n",
            verdict_table(results)]
    if meta.get("checks"):
        head += ["## Checks of this run\n", checks_markdown(meta["checks"])]
    if meta.get("heldout_gate"):
        head += ["## Held-out gate: contact timing\n",
                 "AUROC of the model's predicted contact mass (RGB-to-tactile, mean over covered pixels) for "
                 "\"this frame has contact\" over the frames of the (episode, hand) streams with contact; the "
                 "controls feed the same model the RGB of another episode's frame at a random moment "
                 "(mis-paired) and at the same relative moment (phase-matched); the clock reads no image: "
                 "P(contact | tenth of the episode) measured on the test part. Best lag shift: where "
                 "predicted and measured contact agree best over shifts of +-1 s (negative: the RGB lags; "
                 "lag.png plots the curves). Then F-RMSE over covered "
                 "pixels per frame, pooled and on contact frames (reported, not required), against the better "
                 "of all zeros and the mis-paired model (handtouch/bench/timing.py).\n",
                 heldout_markdown(meta["heldout_gate"])]
    if meta.get("misalignment_control"):
        head += ["## Misalignment control\n",
                 "RGB probes (handtouch/rgb_pretrain.py) trained and scored with RGB aligned, shifted by >= "
                 "1 s within the episode, and taken from another episode; the model column re-runs the "
                 "trained model's RGB-to-tactile track with the frame mis-paired at evaluation time.\n",
                 control_markdown(meta["misalignment_control"])]
    return "\n".join([
        *head,
        "## Covered pixels (f_covered, h_covered)\n",
        "F- over the glove's sensor-covered pixels, H- over the covered pixels of the hidden part.\n",
        markdown_table(results, COLUMNS),
        "## Whole canvas (f_full, h_full)\n",
        "F- over all 224x224 canvas pixels, H- over every pixel of the hidden part (the paper's "
        "\"full tactile map\" convention; uncovered pixels have target 0).\n",
        markdown_table(results, FULL_COLUMNS),
        "## Retrieval and its chance levels\n",
        "1-vs-20, tie-aware (SSIM ties are equally right; embedding ties broken at random, in expectation). "
        "constant: a constant embedding (per-query chance given SSIM ties); shuffled: the model's "
        "embeddings permuted across items; theory: 1/C and 5/C, chance without ties.\n",
        markdown_table(results, RETRIEVAL_COLUMNS),
    ])


def write_results(out_dir: str | Path, results: dict[str, dict[str, dict]], meta: dict | None = None) -> dict:
    """Write results.json ({"meta", "results"}) and results.md; returns the JSON document."""
    doc = {"meta": meta or {}, "results": results}
    write_text_atomic(Path(out_dir) / "results.json", json.dumps(doc, indent=2, sort_keys=True) + "\n")
    write_text_atomic(Path(out_dir) / "results.md", results_markdown(results, meta))
    return doc


def _colour(tactile: np.ndarray, coverage: np.ndarray | None = None) -> np.ndarray:
    """(H,W) values in [0,1] -> BGR uint8 (inferno); uncovered pixels dimmed grey."""
    u8 = (np.clip(np.nan_to_num(tactile), 0.0, 1.0) * 255).round().astype(np.uint8)
    img = cv2.applyColorMap(u8, cv2.COLORMAP_INFERNO)
    if coverage is not None:
        img[coverage < 0.5] = (img[coverage < 0.5] // 3 + 40)
    return img


def _text(img, text, xy, scale=0.42, colour=(230, 230, 230)) -> None:
    cv2.putText(img, text, xy, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def colour_bar(width: int) -> np.ndarray:
    """A legend strip: the colour scale of the maps from 0 to 1 with ticks, and what grey and the cyan
    outline mean."""
    strip = np.zeros((44, width, 3), np.uint8)
    x0, x1 = 40, max(41, min(width // 2, 400))
    ramp = np.linspace(0.0, 1.0, x1 - x0, dtype=np.float32)[None, :].repeat(12, 0)
    strip[6:18, x0:x1] = _colour(ramp)
    for v in (0.0, 0.25, 0.5, 0.75, 1.0):
        x = int(x0 + v * (x1 - x0 - 1))
        strip[18:22, x] = 255
        _text(strip, f"{v:g}", (x - 8, 36), 0.38)
    _text(strip, "map", (4, 16), 0.38)
    _text(strip, "pressure, 0-1 (|pred-GT|: error, same scale). dim grey: no sensor; cyan outline: hidden "
          "part", (x1 + 12, 16), 0.38)
    return strip


def render_lag_curves(report: dict, path: str | Path, fps: float = 30.0) -> np.ndarray:
    """lag.png: per group of the held-out gate (test, held-out, stress), the AUROC of predicted contact
    for measured contact moved by each shift, with 0.5 (chance) and the best shift marked."""
    groups = [(g["where"], g["lag"]) for g in _groups(report) if g.get("lag")]
    if report.get("lag"):
        groups.append((f"pooled, the check: {report['lag']['where']}", report["lag"]["curve"]))
    if not groups:
        raise ValueError("render_lag_curves: the report has no lag curves")
    legend_h = 20 * len(groups) + 8
    w, h, left, bottom, top = 720, 360 + legend_h, 56, 56 + legend_h, 30
    img = np.full((h, w, 3), 255, np.uint8)
    shifts = groups[0][1]["shifts"]
    lo, hi = shifts[0], shifts[-1]

    def xy(shift, value):
        x = left + (shift - lo) / max(hi - lo, 1) * (w - left - 20)
        y = top + (1.0 - value) / 0.6 * (h - top - bottom)        # the axis runs 0.4 .. 1.0
        return int(round(x)), int(round(min(max(y, top), h - bottom)))

    black, grey = (0, 0, 0), (170, 170, 170)
    cv2.rectangle(img, xy(lo, 1.0), xy(hi, 0.4), black, 1)
    for v in (0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0):
        _text(img, f"{v:.1f}", (8, xy(lo, v)[1] + 4), 0.38, black)
    cv2.line(img, xy(lo, 0.5), xy(hi, 0.5), grey, 1)
    for s in range(lo, hi + 1, max(1, (hi - lo) // 6)):
        x = xy(s, 0.4)[0]
        _text(img, f"{s}", (x - 8, h - bottom + 16), 0.38, black)
    cv2.line(img, xy(0, 1.0), xy(0, 0.4), grey, 1)
    _text(img, f"shift of measured contact (frames at {fps:g} fps; negative: the RGB lags the glove)",
          (left, h - bottom + 38), 0.42, black)
    _text(img, "contact-timing AUROC with measured contact shifted (grey: chance 0.5, no shift)", (left, 18), 0.42,
          black)
    colours = [(200, 90, 30), (40, 40, 220), (40, 160, 40), (150, 60, 150)]
    for k, (where, curve) in enumerate(groups):
        colour = colours[k % len(colours)]
        pts = [xy(s, v) for s, v in zip(curve["shifts"], curve["auroc"]) if v is not None]
        if len(pts) > 1:
            cv2.polylines(img, [np.array(pts, np.int32)], False, colour, 2, cv2.LINE_AA)
        if curve.get("best_shift") is not None:
            cv2.circle(img, xy(curve["best_shift"], curve["best_auroc"]), 5, colour, -1, cv2.LINE_AA)
        y = h - legend_h + 14 + 20 * k        # the legend, under the axis: it hides no curve
        cv2.line(img, (left, y - 4), (left + 24, y - 4), colour, 3)
        _text(img, f"{where}: best shift {curve.get('best_shift')} frames", (left + 32, y), 0.42, black)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")
    return img


def render_predictions(examples: dict[str, np.ndarray], path: str | Path, title: str = "") -> np.ndarray:
    """Rows: frames; columns: RGB, GT, inpaint (hidden part outlined), rgb2tactile, prediction, |pred-GT|.

    `examples` as returned by examples.collect_examples. Writes a PNG, returns the BGR image.
    """
    n = len(examples["gt"])
    if n == 0:
        raise ValueError("render_predictions: no example frames")
    size = examples["gt"].shape[-1]
    label_h = 18
    rows = []
    for i in range(n):
        cov = examples["coverage"][i]
        inp = _colour(examples["inpaint"][i], cov)
        edges = cv2.morphologyEx(examples["mask"][i].astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8))
        inp[edges > 0] = (255, 255, 0)
        panels = [
            cv2.cvtColor(examples["rgb"][i], cv2.COLOR_RGB2BGR),
            _colour(examples["gt"][i], cov),
            inp,
            _colour(examples["rgb2tactile"][i], cov),
            _colour(examples["prediction"][i], cov),
            _colour(np.abs(examples["prediction"][i] - examples["gt"][i]), cov),
        ]
        rows.append(np.concatenate([cv2.resize(p, (size, size), interpolation=cv2.INTER_AREA) for p in panels], 1))
    grid = np.concatenate(rows, 0)
    header = np.zeros((label_h * (2 if title else 1), grid.shape[1], 3), np.uint8)
    for j, name in enumerate(PANEL_COLUMNS):
        cv2.putText(header, name, (j * size + 4, header.shape[0] - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (255, 255, 255), 1, cv2.LINE_AA)
    if title:
        cv2.putText(header, title, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (200, 200, 200), 1, cv2.LINE_AA)
    img = np.concatenate([header, grid, colour_bar(grid.shape[1])], 0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")
    return img
