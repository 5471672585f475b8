"""The dataset card's plots, drawn with cv2: bar charts, histograms with ticked axes, region heat maps.

`value_histogram_chart` draws a glove's value histogram over the x range the
stats chose to fit its data (`htdata stats` "value_histogram": range [0, hi],
hi a round number at or above the p99.9 of the positive values), with ticks,
so a faint raw-count glove does not show as one bar at 0.
"""

from __future__ import annotations

import cv2
import numpy as np

from htdata.format.canvas import CANVAS
from htdata.inspect.preview import BAR_H, draw_colour_bar, region_outline

BG = (255, 255, 255)            # BGR, white plots for a white page
INK = (40, 40, 40)
BAR = (180, 119, 31)
FONT = cv2.FONT_HERSHEY_SIMPLEX
X_TICKS = 5                     # labelled x ticks of a histogram (ends included)


def bar_chart(labels: list[str], values: list[float], title: str, unit: str = "", width: int = 560) -> np.ndarray:
    """Horizontal bars, one row per label, value written at the end of each bar."""
    row, left, top = 20, 170, 30
    img = np.full((top + row * max(len(labels), 1) + 10, width, 3), BG, np.uint8)
    cv2.putText(img, title, (8, 18), FONT, 0.5, INK, 1, cv2.LINE_AA)
    top_value = max([float(v) for v in values] + [1e-12])
    for i, (label, value) in enumerate(zip(labels, values)):
        y = top + i * row
        cv2.putText(img, str(label)[:24], (8, y + 13), FONT, 0.4, INK, 1, cv2.LINE_AA)
        w = int(round((width - left - 90) * float(value) / top_value))
        cv2.rectangle(img, (left, y + 2), (left + max(w, 1), y + row - 4), BAR, cv2.FILLED)
        cv2.putText(img, f"{value:g}{unit}", (left + w + 6, y + 13), FONT, 0.4, INK, 1, cv2.LINE_AA)
    if not labels:
        cv2.putText(img, "(none)", (left, top + 13), FONT, 0.4, INK, 1, cv2.LINE_AA)
    return img


def histogram_chart(counts: list[int], lo: float, hi: float, title: str, log: bool = True,
                    width: int = 560, height: int = 170) -> np.ndarray:
    """Vertical bars over [lo, hi] (log10(1 + count) heights when `log`), X_TICKS labelled x ticks."""
    img = np.full((height, width, 3), BG, np.uint8)
    cv2.putText(img, title, (8, 18), FONT, 0.5, INK, 1, cv2.LINE_AA)
    c = np.asarray(counts, np.float64)
    h = np.log10(1 + c) if log else c
    base, plot_h, x0, x1 = height - 24, height - 54, 40, width - 12
    if h.size and h.max() > 0:
        bw = (x1 - x0) / h.size
        for i, v in enumerate(h / h.max()):
            cv2.rectangle(img, (int(x0 + i * bw), base - int(v * plot_h)), (int(x0 + (i + 1) * bw) - 1, base),
                          BAR, cv2.FILLED)
    cv2.line(img, (x0, base), (x1, base), INK, 1)
    cv2.line(img, (x0, base), (x0, base - plot_h), INK, 1)
    for k in range(X_TICKS):
        value = lo + k * (hi - lo) / (X_TICKS - 1)
        x = int(round(x0 + k * (x1 - x0) / (X_TICKS - 1)))
        cv2.line(img, (x, base), (x, base + 4), INK, 1)
        text = f"{value:.3g}"
        tw = cv2.getTextSize(text, FONT, 0.4, 1)[0][0]
        cv2.putText(img, text, (min(max(x - tw // 2, 2), width - tw - 2), base + 18), FONT, 0.4, INK, 1, cv2.LINE_AA)
    for frac, count in _y_ticks(c, log):
        y = base - int(round(frac * plot_h))
        cv2.line(img, (x0 - 3, y), (x0, y), INK, 1)
        cv2.putText(img, _count_label(count), (2, y + 4), FONT, 0.32, INK, 1, cv2.LINE_AA)
    cv2.putText(img, "log count" if log else "count", (x1 - 80, 34), FONT, 0.35, INK, 1, cv2.LINE_AA)
    return img


def _y_ticks(counts: np.ndarray, log: bool) -> list[tuple[float, float]]:
    """(height fraction, count) of the y-axis ticks: 0, the middle and the top of the tallest bar.

    Log charts place their ticks at powers of ten (bar height log10(1 + count)), so the
    labels read as counts whatever the scale.
    """
    top = float(counts.max()) if counts.size else 0.0
    if top <= 0:
        return [(0.0, 0.0)]
    if not log:
        return [(0.0, 0.0), (0.5, top / 2), (1.0, top)]
    h_top = np.log10(1 + top)
    powers = [(np.log10(1 + 10.0 ** k) / h_top, 10.0 ** k) for k in range(int(np.floor(np.log10(top))) + 1)]
    ticks = [(0.0, 0.0)]
    for frac, count in powers:    # keep labels apart: no tick within 12% of the chart of another
        if frac - ticks[-1][0] >= 0.12 and 1.0 - frac >= 0.12:
            ticks.append((frac, count))
    return ticks + [(1.0, top)]


def _count_label(count: float) -> str:
    return f"{count / 1e6:.3g}M" if count >= 1e6 else f"{count / 1e3:.3g}k" if count >= 1e3 else f"{count:.3g}"


def region_heatmap(glove: dict, region_map: np.ndarray, region_ids: dict[str, int], title: str) -> np.ndarray:
    """Canonical hand, each place filled by its contact frequency (inferno, 0..the highest one), with a value bar."""
    img = np.full((CANVAS + 28 + 6 + BAR_H, CANVAS + 16, 3), (32, 32, 32), np.uint8)
    values = np.zeros(region_map.shape, np.float32)
    known = np.zeros(region_map.shape, bool)
    for name, r in glove["regions"].items():
        if name in region_ids and r["contact_frequency"] is not None:
            mask = region_map == region_ids[name]
            values[mask] = r["contact_frequency"]
            known |= mask
    vmax = max(float(values.max()), 0.01)
    panel = cv2.applyColorMap(np.round(np.clip(values / vmax, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
    panel[~known] = (90, 90, 90)
    panel[region_map == 0] = (32, 32, 32)
    panel[region_outline(region_map)] = (255, 255, 255)
    _label_fingers(panel, region_map, region_ids)
    img[28:28 + CANVAS, 8:8 + CANVAS] = panel
    cv2.putText(img, title[:32], (8, 18), FONT, 0.45, (235, 235, 235), 1, cv2.LINE_AA)
    draw_colour_bar(img, 8, 28 + CANVAS + 6, CANVAS, vmax, "contact frequency (share of frames)")
    return img


def _label_fingers(panel: np.ndarray, region_map: np.ndarray, region_ids: dict[str, int]) -> None:
    """Write each digit's and the palm's name at the centre of its places (e.g. "index" over index.*)."""
    groups: dict[str, list[int]] = {}
    for name, rid in region_ids.items():
        groups.setdefault(name.split(".")[0], []).append(rid)
    for group, ids in groups.items():
        ys, xs = np.nonzero(np.isin(region_map, ids))
        if ys.size == 0:
            continue
        size = cv2.getTextSize(group, FONT, 0.33, 1)[0]
        org = (int(xs.mean()) - size[0] // 2, int(ys.mean()) + size[1] // 2)
        cv2.putText(panel, group, org, FONT, 0.33, (0, 0, 0), 3, cv2.LINE_AA)       # dark rim: readable on any fill
        cv2.putText(panel, group, org, FONT, 0.33, (255, 255, 255), 1, cv2.LINE_AA)


def value_histogram_chart(h: dict, title: str) -> np.ndarray:
    """A glove's value histogram ("value_histogram" of `htdata stats`) over its fitted range, ticked."""
    lo, hi = h.get("range", [0.0, 1.0])
    above = int(h.get("above", 0))
    note = f", {above} above {hi:g}" if above else ""
    return histogram_chart(h["counts"], lo, hi, f"{title}: values > 0 ({h['zeros']} exact zeros{note})")
