"""`htdata stats DATASET [--version N] [--by GROUP] [--json] [--health OUT.png]`: what a dataset holds."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from htdata.commands.outputs import output_path
from htdata.commands.version_arg import version_arg
from htdata.glove.health import CLASSES
from htdata.inspect import stats
from htdata.resources import PIPELINES_DIR

EPILOG = """\
The text output starts with a short summary (what --brief prints alone), then per glove:
  contact        fraction of frames in contact by the glove hand's contact rule (docs/USAGE.md "Contact":
                 with a noise floor, a few taxels above it; without one, any taxel above 0.02)
  scale          where a glove's pressed values use less than half of 0..1: a suggested `scale` and the
                 lines to paste into the pipeline TOML (docs/USAGE.md "A scale from the data")
  values p1..max quantiles of the normalised [0,1] taxel values; raw: the same in glove units
  health         taxels flagged dead / stuck / noisy / hot (htdata stats --health OUT.png draws them);
                 "quiet and never pressed" = taxels that never left zero, so nothing can be said
  regions        taxels per hand region, how often it was in contact, its mean pressure when pressed
then frames and duration per task and per scene. Numbers are cached per episode in DATASET/stats/,
so a second run (or one after appending an episode) computes only what changed.

Examples:
  htdata stats data/dataset --brief
  htdata stats data/dataset --by task --health health.png
"""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.add_argument("dataset", help="committed dataset directory (or URL)")
    parser.add_argument("--version", type=version_arg, default=None, metavar="N", help="version (default: current)")
    parser.add_argument("--by", choices=stats.GROUPINGS, default=None,
                        help="break the glove numbers down per task / scene / source, or merge per layout / hand")
    parser.add_argument("--json", action="store_true", help="print the full JSON (per-taxel mean/std included)")
    parser.add_argument("--brief", action="store_true", help="print only the short summary (a few lines)")
    parser.add_argument("--health", type=Path, default=None, metavar="OUT.png",
                        help="also draw the taxel health map in the canonical hand frame")
    parser.add_argument("--no-cache", action="store_true",
                        help="compute every episode, read and write no DATASET/stats/ entry")


def run(args: argparse.Namespace) -> int:
    cache = None if args.no_cache else "default"
    try:
        summary = stats.dataset_stats(args.dataset, version=args.version, by=args.by, cache_dir=cache)
        health_png = (stats.write_health_map(args.dataset, output_path(args.health, "stats"), args.version,
                                             cache_dir=cache)
                      if args.health is not None else None)
    except (ValueError, FileNotFoundError, KeyError, OSError) as exc:
        print(f"htdata stats: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        for line in brief_lines(summary) + ([] if args.brief else [""] + text_lines(summary)):
            print(line)
    if summary["cache"].get("cache_error"):
        print(f"htdata stats: warning: stats not cached: {summary['cache']['cache_error']}", file=sys.stderr)
    for bad in summary["nan_samples"]:
        print(f"htdata stats: warning: {bad['key']} ({bad['hand']} hand, episode {bad['episode']} frame "
              f"{bad['frame']}): {bad['nonfinite_pixels']} NaN/Inf pixel(s); map left out", file=sys.stderr)
    if health_png is not None:
        print(f"wrote {health_png}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def brief_lines(s: dict) -> list[str]:
    """A few lines a newcomer can read: size, tasks, and per glove contact and flagged taxels."""
    duration = sum(row["duration_s"] for row in s["tasks"].values())
    rules = s.get("contact_rules") or []
    out = [f"{s['dataset']} version {s['version']}: {s['episodes']} episodes, {s['frames']} frames "
           f"({duration / 60:.1f} min), {len(s['tasks'])} tasks, {len(s['scenes'])} scenes",
           # the rule each glove hand's calibration gives (htdata/glove/contact.py), not a fixed threshold
           f"contact = a frame with {rules[0]} (normalised 0..1)" if len(rules) == 1 else
           "contact = a frame where the glove hand's contact rule holds (htdata/glove/contact.py; per glove below)"]
    for g in s["gloves"]:
        name = " / ".join(str(g[k]) for k in ("task", "scene", "source", "layout", "hand") if k in g)
        flagged = sum(g["health"]["counts"][k] for k in CLASSES)
        out.append(f"  {name}: {g['episodes']} episodes, contact in {100 * (g['contact_fraction'] or 0):.0f}% "
                   f"of frames, {flagged} taxel-episodes flagged unhealthy"
                   + (f" (contact: {g['contact_rule']})" if len(rules) > 1 and g.get("contact_rule") else ""))
    if not s["gloves"]:
        out.append("  no tactile frames")
    return out + scale_lines(s)


def scale_lines(s: dict) -> list[str]:
    """Per layout whose maps look faint: the suggested `scale` and the lines to paste (htdata/inspect/scalehint.py)."""
    out = []
    for layout, hint in (s.get("scale") or {}).items():
        if not hint.get("toml"):
            continue
        pipes = hint.get("pipelines") or ["PIPELINE"]
        shipped = [p for p in pipes if (PIPELINES_DIR / f"{p}.toml").is_file()]
        mine = {p: (f"my_{p}.toml" if p in shipped else f"{p}.toml") for p in pipes}
        out.append(f"scale {layout}: {hint['reason']}. Add these lines to the pipeline "
                   f"{' and '.join(mine.values())} (under the layout's table; add the table if it has none):")
        out += [f"    {line}" for line in hint["toml"].splitlines()]
        out += [f"  first: htdata pipelines show {p} > {mine[p]}   (a shipped pipeline: copy it to edit)"
                for p in shipped]
        out += [f"  then: htdata renormalise {s['dataset']} --pipeline {mine[p]}" for p in pipes]
    return out


def text_lines(s: dict) -> list[str]:
    c = s["cache"]
    out = [f"{s['dataset']} version {s['version']}: {s['episodes']} episodes, {s['frames']} frames "
           f"(stats: {c['computed']} episodes computed, {c['cached']} cached)",
           f"values: {s['values']}; contact per glove and hand from its calibration (htdata/glove/contact.py), "
           f"'old' = any taxel > {s['contact_threshold']}"]
    if not s["gloves"]:
        out.append("no tactile frames")
    for g in s["gloves"]:
        name = " / ".join(str(g[k]) for k in ("task", "scene", "source", "layout", "hand") if k in g)
        q = g["quantiles"]
        h = g["health"]
        flagged = ", ".join(f"{k} {h['counts'][k]}" for k in CLASSES if h["counts"][k]) or "none"
        out += [f"\n{name}: {g['episodes']} episodes, {g['frames']} frames, contact {_fmt(g['contact_fraction'])} "
                f"({g.get('contact_rule') or '-'}; old {_fmt(g.get('contact_fraction_threshold'))})",
                f"  values p1 {_fmt(q['p1'])}  p50 {_fmt(q['p50'])}  p99 {_fmt(q['p99'])}  max {_fmt(q['max'])}"
                + (f"; scale: {hint['reason']}" if (hint := (s.get("scale") or {}).get(g["layout"])) else ""),
                *([f"  raw (glove units, {g['frames_from_raw']} frames) " + "  ".join(
                    f"{k} {_fmt(g['raw_quantiles'][k])}" for k in ("p1", "p50", "p99", "max"))]
                  if g.get("raw_quantiles") else []),
                f"  health: {h['taxels_assessed']} taxel-episodes assessed ({h['episodes_not_assessed']} episodes "
                f"too short), flagged: {flagged}; quiet and never pressed: {h['unexercised']}"
                + (f"; drift: {h['drift']}" if h.get("drift") else ""),
                "  region              taxels  contact  mean pressure"]
        for region, r in g["regions"].items():
            out.append(f"  {region:<20}{r['taxels']:>6}  {_fmt(r['contact_frequency']):>7}  "
                       f"{_fmt(r['mean_pressure']):>13}")
    for field, table in (("task", s["tasks"]), ("scene", s["scenes"])):
        out.append(f"\n{field:<20} episodes  frames  duration_s  hands (episodes left/right)")
        for name, row in table.items():
            out.append(f"{name:<20} {row['episodes']:>8}  {row['frames']:>6}  {row['duration_s']:>10.1f}  "
                       f"{row['hands']['left']}/{row['hands']['right']}")
    return out
