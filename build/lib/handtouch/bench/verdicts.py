"""Verdicts: each trained model's tracks against the reference predictors.

A model has learned a track only if it beats what a predictor with no learning gets on
the same items. Per model and part (`VERDICTS`, covered-pixel metrics, lower RMSE better):

  retrieval        Hit@1 > the highest chance level (1/20, constant and shuffled embeddings)
  reconstruction   F-RMSE < all zeros
  inpaint F        F-RMSE < copy-last (the visible map copied; holes 0)
  inpaint H        H-RMSE < all zeros (copy-last leaves the hole at 0: the same figure)
  rgb2tactile      F-RMSE < all zeros (copy-last has no tactile input here: also zeros)
  prediction       F-RMSE < the better of all zeros and copy-last (frame T-1 copied)

Each verdict is "ok" or "not yet", always with both numbers: a check the smoke budget
cannot pass yet is reported with what was measured, never left out. Which verdicts fail
the smoke run is the smoke's choice (handtouch.smoke), not this module's.
"""

from __future__ import annotations

import math

from handtouch.bench.report import cell

ZEROS, COPY_LAST = "zeros-ref", "copy-last-ref"
REFERENCES = (ZEROS, COPY_LAST)
# (label, track, region, key, references whose best value is the bar; "chance" = retrieval's levels)
VERDICTS = (
    ("retrieval Hit@1", "retrieval", None, "hit_at_1", ("chance",)),
    ("reconstruction F-RMSE", "reconstruction", "f_covered", "rmse", (ZEROS,)),
    ("inpaint F-RMSE", "inpaint", "f_covered", "rmse", (COPY_LAST,)),
    ("inpaint H-RMSE", "inpaint", "h_covered", "rmse", (ZEROS,)),
    ("rgb2tactile F-RMSE", "rgb2tactile", "f_covered", "rmse", (ZEROS,)),
    ("prediction F-RMSE", "prediction", "f_covered", "rmse", (ZEROS, COPY_LAST)),
)
CHANCE_KEYS = ("chance_hit_at_1", "constant_hit_at_1", "shuffled_hit_at_1")


def _known(x) -> bool:
    return x is not None and math.isfinite(x)


def verdict(results: dict, model: str, part: str, spec: tuple) -> dict:
    """One verdict: {"label", "value", "reference", "against", "ok"} (ok None: not measured)."""
    label, track, region, key, refs = spec
    metrics = results[model][part]
    value = cell(metrics, track, region, key)
    if refs == ("chance",):
        levels = [cell(metrics, track, None, k) for k in CHANCE_KEYS]
        bar = max(levels) if all(_known(x) for x in levels) else None
        ok = _known(value) and _known(bar) and value > bar
        against = "chance"
    else:
        bars = {r: cell(results[r][part], track, region, key) for r in refs if part in results.get(r, {})}
        bars = {r: v for r, v in bars.items() if _known(v)}
        against = min(bars, key=bars.get) if bars else "/".join(refs)
        bar = bars.get(against)
        ok = _known(value) and _known(bar) and value < bar
    measured = _known(value) and _known(bar)
    return {"label": label, "value": value, "reference": bar, "against": against,
            "ok": bool(ok) if measured else None}


def model_verdicts(results: dict) -> dict[str, dict[str, list[dict]]]:
    """{model: {part: [verdict per VERDICTS row]}} for every model that is not a reference."""
    return {m: {p: [verdict(results, m, p, spec) for spec in VERDICTS] for p in parts}
            for m, parts in results.items() if m not in REFERENCES}


def _text(v: dict) -> str:
    if v["ok"] is None:
        return "–"
    op = (">" if v["against"] == "chance" else "<") if v["ok"] else ("<=" if v["against"] == "chance" else ">=")
    return f"{'ok' if v['ok'] else 'not yet'} {v['value']:.3f} {op} {v['reference']:.3f} {v['against']}"


def verdict_table(results: dict) -> str:
    """Markdown: one row per model (part), one verdict column per track."""
    header = "| Model | " + " | ".join(label for label, *_ in VERDICTS) + " |"
    rows = [header, "|---|" + "---|" * len(VERDICTS)]
    for model, parts in model_verdicts(results).items():
        for part, vs in parts.items():
            rows.append(f"| {model} ({part}) | " + " | ".join(_text(v) for v in vs) + " |")
    return "\n".join(rows) + "\n"
