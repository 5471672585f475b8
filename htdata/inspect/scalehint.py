"""A `scale` suggestion per glove layout, from the pressed values of `htdata stats`.

Real raw-count gloves press to a small share of their full scale (0.03-0.44
of it on a real 32x32 knit glove, p99 0.007-0.03), so their maps look empty
on the 0..1 colour scale. Per layout, the suggestion takes the PRESSED values
(values above each episode hand's contact level, htdata/glove/contact.py,
from the stats' fixed-bin histograms: HIST_BINS bins of 0.001, so a value is
known to 0.001) and proposes

    scale = current scale x TARGET / (the SUGGEST_QUANTILE of the pressed values)

rounded DOWN to two significant digits, so that about 0.1% of pressed
values saturate at 1. Only when that quantile is below SUGGEST_BELOW (the
maps use less than a quarter of the scale: a glove whose firm presses reach
0.4 is not faint, its light presses are, and the project's own sample left
glove is such a one) and there are at least MIN_PRESSED
pressed values; otherwise the current scale is said to fit (or why nothing
can be said). The line to paste is `scale = S` under the layout's
`[normalise.<layout id>]` table of the pipeline TOML the episodes were
ingested with (their `source`: a shipped pipeline is first copied with
`htdata pipelines show NAME > my_NAME.toml`), then
`htdata renormalise DATASET --pipeline my_NAME.toml` remakes the maps.
"""

from __future__ import annotations

import math

import numpy as np

from htdata.inspect.episodestats import HIST_BINS, quantile

SUGGEST_QUANTILE = 0.999
SUGGEST_BELOW = 0.25       # pressed values' p99.9 below this: the maps use less than a quarter of the colour scale
TARGET = 1.0               # where the p99.9 of pressed values lands with the suggested scale
MIN_PRESSED = 1000         # fewer pressed taxel values than this: too few to suggest anything


def _floor_sig(x: float, digits: int = 2) -> float:
    """x rounded DOWN to `digits` significant digits (33.2 -> 33, 2.27 -> 2.2)."""
    if x <= 0 or not math.isfinite(x):
        return x
    step = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return round(math.floor(x / step + 1e-9) * step, 12)


def _current_scale(manifest: dict, ep: dict, hand: str) -> float:
    cal = (ep.get("calibration") or {}).get(hand)
    entry = manifest.get("calibrations", {}).get(cal) if cal else None
    return float((entry or {}).get("scale", 1.0))


def scale_suggestions(reader, per_episode: list[dict]) -> dict[str, dict]:
    """{layout id: {pressed, p99_9, scale, suggested_scale, toml, reason}} (see the module docstring)."""
    acc: dict[str, dict] = {}
    for ep, st in zip(reader.episodes, per_episode):
        for hand, h in st["hands"].items():
            a = acc.setdefault(h["layout"], {"hist": np.zeros(HIST_BINS, np.int64), "scales": set(), "pipelines": set()})
            a["pipelines"].add(str(ep.get("source") or ""))
            level = float((h.get("contact_rule") or {}).get("level", 0.0))
            start = min(int(math.ceil(level * HIST_BINS)), HIST_BINS)   # bins whose values lie above the level
            hist = np.asarray(h["hist"], np.int64)
            a["hist"][start:] += hist[start:]
            a["scales"].add(_current_scale(reader.manifest, ep, hand))
    return {layout: {**_suggest(layout, a["hist"], a["scales"]), "pipelines": sorted(a["pipelines"] - {""})}
            for layout, a in sorted(acc.items())}


def _suggest(layout: str, hist: np.ndarray, scales: set) -> dict:
    pressed = int(hist.sum())
    q = quantile(0, hist, SUGGEST_QUANTILE) if pressed else None
    out = {"pressed": pressed, "p99_9": None if q is None else round(q, 4),
           "scale": next(iter(scales)) if len(scales) == 1 else None, "suggested_scale": None, "toml": None}
    if pressed < MIN_PRESSED:
        out["reason"] = f"only {pressed} pressed taxel values (need {MIN_PRESSED}): no suggestion"
    elif len(scales) != 1:
        out["reason"] = f"episodes were normalised with different scales ({sorted(scales)}): no suggestion"
    elif q >= SUGGEST_BELOW:
        out["reason"] = f"scale {out['scale']:g} fits: pressed values reach {q:.3g} (p99.9)"
    else:
        s = _floor_sig(out["scale"] * TARGET / max(q, 1.0 / HIST_BINS))
        out["suggested_scale"] = s
        out["toml"] = f"[normalise.{layout}]\nscale = {s:g}"
        out["reason"] = (f"pressed values reach only {q:.3g} of 1 (p99.9) at scale {out['scale']:g}: maps look "
                         f"faint; scale {s:g} puts that at about {TARGET:g}")
    return out


__all__ = ["scale_suggestions", "SUGGEST_QUANTILE", "SUGGEST_BELOW", "TARGET", "MIN_PRESSED"]
