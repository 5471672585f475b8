"""HT-Bench report: results JSON, a markdown table, a predictions PNG.

The table follows the paper's column order, one row per model per part;
RMSE / cIoU cells are per-frame means (pooled values are in the JSON).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

# (header, track, region, key) in the paper's order.
COLUMNS: tuple[tuple[str, str, str | None, str], ...] = (
    ("Retrieval Hit@1", "retrieval", None, "hit_at_1"),
    ("Retrieval R@5", "retrieval", None, "recall_at_5"),
    ("Inpaint F-RMSE", "inpaint", "full", "rmse"),
    ("F-cIoU", "inpaint", "full", "ciou"),
    ("H-RMSE", "inpaint", "hole", "rmse"),
    ("H-cIoU", "inpaint", "hole", "ciou"),
    ("RGB2T F-RMSE", "rgb2tactile", "full", "rmse"),
    ("F-cIoU", "rgb2tactile", "full", "ciou"),
    ("Pred F-RMSE", "prediction", "full", "rmse"),
    ("F-cIoU", "prediction", "full", "ciou"),
)
PANEL_COLUMNS = ("RGB", "GT", "inpaint", "rgb2tactile", "prediction", "|pred-GT|")


def cell(metrics: dict, track: str, region: str | None, key: str):
    """The value of one table cell (None when the track was not scored)."""
    node = metrics.get(track)
    if node is None:
        return None
    if region is not None:
        node = node.get(region)
        if node is None:
            return None
    return node.get(key)


def _fmt(v) -> str:
    return "–" if v is None else f"{v:.3f}"


def markdown_table(results: dict[str, dict[str, dict]]) -> str:
    """results: {model name: {part: tracks}} -> markdown table, rows 'model (part)'."""
    header = "| Model | " + " | ".join(h for h, *_ in COLUMNS) + " |"
    rule = "|---|" + "---:|" * len(COLUMNS)
    rows = [header, rule]
    for model, parts in results.items():
        for part, metrics in parts.items():
            vals = [_fmt(cell(metrics, t, r, k)) for _, t, r, k in COLUMNS]
            rows.append(f"| {model} ({part}) | " + " | ".join(vals) + " |")
    return "\n".join(rows) + "\n"


def write_text_atomic(path: str | Path, text: str) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(tmp, 0o644)          # mkstemp creates 0600; results are meant to be shared
    os.replace(tmp, path)


def write_results(out_dir: str | Path, results: dict[str, dict[str, dict]], meta: dict | None = None) -> dict:
    """Write results.json ({"meta", "results"}) and results.md; returns the JSON document."""
    doc = {"meta": meta or {}, "results": results}
    write_text_atomic(Path(out_dir) / "results.json", json.dumps(doc, indent=2, sort_keys=True) + "\n")
    note = ("RMSE / cIoU: per-frame means over covered pixels (F) or covered hidden pixels (H); "
            "retrieval: 1-vs-20, chance Hit@1 0.050, R@5 0.250.\n\n")
    write_text_atomic(Path(out_dir) / "results.md", "# HT-Bench results\n\n" + note + markdown_table(results))
    return doc


def _colour(tactile: np.ndarray, coverage: np.ndarray | None = None) -> np.ndarray:
    """(H,W) values in [0,1] -> BGR uint8 (inferno); uncovered pixels dimmed grey."""
    u8 = (np.clip(np.nan_to_num(tactile), 0.0, 1.0) * 255).round().astype(np.uint8)
    img = cv2.applyColorMap(u8, cv2.COLORMAP_INFERNO)
    if coverage is not None:
        img[coverage < 0.5] = (img[coverage < 0.5] // 3 + 40)
    return img


def render_predictions(examples: dict[str, np.ndarray], path: str | Path, title: str = "") -> np.ndarray:
    """Rows: frames; columns: RGB, GT, inpaint (hidden part outlined), rgb2tactile, prediction, |pred-GT|.

    `examples` as returned by evaluate.collect_examples. Writes a PNG, returns the BGR image.
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
    img = np.concatenate([header, grid], 0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")
    return img
