"""`htdata stats`: what a dataset version holds, from per-episode mergeable stats cached by content.

Stats are computed PER EPISODE (htdata/inspect/episodestats.py: one pass over its
tactile members, never the JPEG) and cached in `DATASET/stats/<key>.json`,
key = sha256 of the stats schema (thresholds, histogram bins, health
version), the sha256 of every shard the episode's samples lie in, the
offset of its first sample, its frame count and the sha256 of its layout
and canonical documents. Shards are immutable, so an entry is written once
(atomically) and never rewritten; a new version reuses every entry whose
episode it did not re-pack: appending one episode costs that episode, a
trim / rm / re-ingest recomputes only the episodes it re-packed. Dataset
numbers are sums of the episodes' (counts, sums, sums of squares,
fixed-bin histograms), so any grouping (`by`) is a merge, not a re-read.

A remote dataset (URL) is computed without a cache unless `cache_dir` is
given; a cache that cannot be written (read-only dataset) is reported in
the result's "cache" entry and the stats are still returned.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic
from htdata.format.table import HANDS, STATS_DIR
from htdata.glove.contact import RULE_VERSION, ContactRule
from htdata.glove.health import CLASSES, HEALTH_VERSION, merge_counts
from htdata.glove.rawhealth import drift_status
from htdata.inspect.episodestats import (
    CONTACT_THRESHOLD,
    HIST_BINS,
    compute_episode,
    dataset_gloves,
    empty_hand,
    merge_hand,
    quantile,
)
from htdata.inspect.healthmap import write_health_map as write_png
from htdata.inspect.scalehint import scale_suggestions
from htdata.inspect.statscache import read_entry
from htdata.read.reader import DatasetReader
from htdata.store import storage
from htdata.store.writable import symlinked_folder

# /2: values from the raw rows where stored (format 3), raw-unit sketches; the key covers the calibration
STATS_SCHEMA = (f"htdata-episode-stats/2 health/{HEALTH_VERSION} bins/{HIST_BINS} contact/{CONTACT_THRESHOLD} "
                f"rule/{RULE_VERSION}")
GROUPINGS = ("task", "scene", "source", "layout", "hand")
QUANTILES = {"p1": 0.01, "p50": 0.50, "p99": 0.99}
HIST_COARSE = 50                  # bins of the summary's value_histogram (divides HIST_BINS)
# value_histogram x ranges: each a whole number of fine bins per coarse bin (HIST_BINS x r / HIST_COARSE)
HIST_RANGES = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0)
Progress = Callable[[int, int], None]


def episode_key(reader: DatasetReader, pos: int) -> str:
    """Content address of episode `pos`'s stats (see the module docstring)."""
    first, n = reader.episode_range(pos)
    manifest = reader.manifest
    ep = reader.episodes[pos]
    shards = sorted({int(s) for s in reader.index["shard"][first:first + n]}) if n else []
    doc = {"schema": STATS_SCHEMA, "shards": [manifest["shards"][s]["sha256"] for s in shards],
           "first_offset": int(reader.index["offset"][first]) if n else None, "frames": n,
           "layouts": {h: manifest["layouts"].get(lid, {}).get("sha256") for h, lid in sorted(ep["layouts"].items())},
           "canonical": manifest.get("canonical", {}).get("sha256"),
           # values from raw rows depend on the calibration: its settings and the episode's fitted arrays
           "calibration": {h: [cid, manifest.get("calibrations", {}).get(cid)]
                           for h, cid in sorted((ep.get("calibration") or {}).items())},
           "calibration_fit": ep.get("calibration_fit")}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def default_cache_dir(root) -> Path | None:
    return None if storage.is_url(root) else Path(root) / STATS_DIR


def episode_stats(reader: DatasetReader, positions: list[int] | None = None, cache_dir=None,
                  progress: Progress | None = None) -> tuple[list[dict], dict]:
    """(stats of each episode in `positions` (default all), {"computed", "cached"} counts).

    Missing entries are computed and written to `cache_dir` (None: no cache).
    """
    positions = list(range(len(reader.episodes))) if positions is None else positions
    cache = Path(cache_dir) if cache_dir is not None else None
    refused = symlinked_folder(cache.parent, cache.name) if cache is not None else None
    if refused:      # entries from outside the dataset are not trusted, none is written there
        cache = None
    keys = {pos: episode_key(reader, pos) for pos in positions}
    paths = {pos: cache / f"{keys[pos]}.json" if cache is not None else None for pos in positions}
    entries = {pos: read_entry(paths[pos]) for pos in dict.fromkeys(positions)}
    info = {"computed": 0, "cached": sum(e is not None for e in entries.values()), "frames_computed": 0}
    if refused:
        info["cache_error"] = refused
    missing = [pos for pos, e in entries.items() if e is None]
    done = len(entries) - len(missing)
    if progress and done:
        progress(done, len(entries))
    for pos, entry in compute_missing(reader, missing):
        entry["key"] = keys[pos]
        entries[pos] = entry
        info["computed"] += 1
        info["frames_computed"] += entry["frames"]
        path = paths[pos]
        if path is not None and not path.exists():
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                write_bytes_atomic(path, (json.dumps(entry, separators=(",", ":")) + "\n").encode())
            except OSError as exc:        # a read-only dataset still gets its stats, uncached
                info["cache_error"] = f"{path.parent}: {exc}"
        done += 1
        if progress:
            progress(done, len(entries))
    return [entries[pos] for pos in positions], info


def compute_missing(reader: DatasetReader, positions: list[int]):
    """Yield (position, stats) of each episode in `positions`, one process.

    (Spreading episodes over worker processes was measured on this 2-core
    machine while it was shared: no gain over one process, and a spawned pool
    would re-run an unguarded calling script; the raw-row path made one
    process fast enough.)
    """
    gloves = dataset_gloves(reader) if positions else {}
    for pos in positions:
        yield pos, compute_episode(reader, pos, gloves)


def _group_key(by: str | None, ep: dict, hand: str, layout: str) -> tuple:
    if by is None:
        return (layout, hand)
    if by == "layout":
        return (layout,)
    if by == "hand":
        return (hand,)
    return (str(ep.get(by)), layout, hand)


def _glove_summary(acc: dict, gloves: dict, health: dict) -> dict:
    hist = np.asarray(acc["hist"], np.int64)
    frames = acc["frames"]
    out = {"episodes": acc["episodes"], "layout": acc["layout"], "frames": frames,
           "contact_fraction": round(acc["contact_frames"] / frames, 6) if frames else None,
           "contact_fraction_threshold": round(acc["contact_frames_threshold"] / frames, 6) if frames else None,
           "contact_rule": "; ".join(ContactRule(**r).describe() for r in acc["contact_rules"]) or None,
           "quantiles": {k: quantile(acc["zeros"], hist, q) for k, q in QUANTILES.items()},
           "regions": {}, "health": health}
    out["quantiles"]["max"] = acc["max"] if frames else None
    out["frames_from_raw"] = acc["frames_from_raw"]
    if acc.get("raw_hist") is not None and acc["raw_count"]:
        # raw glove units (the layout's value convention); quantiles of values clipped to [0, raw_top]
        raw_hist, top = np.asarray(acc["raw_hist"], np.int64), acc["raw_top"]
        out["raw_quantiles"] = {k: _scaled(quantile(acc["raw_zeros"], raw_hist, q), top) for k, q in QUANTILES.items()}
        out["raw_quantiles"].update({"min": acc["raw_min"], "max": acc["raw_max"], "range": [0.0, top]})
    out["value_histogram"] = fitted_histogram(int(acc["zeros"]), hist)
    for name, r in sorted(acc["regions"].items()):
        out["regions"][name] = {
            "taxels": r["taxels"],
            "contact_frequency": round(r["contact_frames"] / frames, 6) if frames else None,
            "mean_pressure": round(r["pressure_sum"] / r["pressure_count"], 6) if r["pressure_count"] else None}
    glove = gloves.get(acc["layout"])
    if acc["taxel_sum"] is not None and glove is not None and frames:
        mean = np.asarray(acc["taxel_sum"]) / frames
        std = np.sqrt(np.maximum(np.asarray(acc["taxel_sumsq"]) / frames - mean ** 2, 0.0))
        out["taxel_mean"], out["taxel_std"] = _on_grid(mean, glove), _on_grid(std, glove)
    return out


def fitted_histogram(zeros: int, hist: np.ndarray) -> dict:
    """Coarse twin of the fixed-bin histogram for plots: exact zeros + HIST_COARSE bins over (0, hi], hi the
    smallest of HIST_RANGES at or above the p99.9 of the positive values (a faint glove's values fill the plot,
    not its first bar); "above" counts the values beyond hi."""
    q = quantile(0, hist, 0.999) if hist.sum() else None
    hi = next((r for r in HIST_RANGES if q is not None and q <= r), 1.0)
    fine = int(round(hi * HIST_BINS))
    return {"zeros": zeros, "range": [0.0, hi], "above": int(hist[fine:].sum()),
            "counts": hist[:fine].reshape(HIST_COARSE, -1).sum(axis=1).tolist()}


def _scaled(q: float | None, top: float) -> float | None:
    return None if q is None else round(q * top, 6)


def _on_grid(values: np.ndarray, glove) -> list:
    grid = np.full(glove.layout.grid, np.nan)
    grid[glove.layout.live_mask] = values
    return [[None if np.isnan(v) else round(float(v), 6) for v in row] for row in grid]


def summarise(reader: DatasetReader, per_episode: list[dict], by: str | None = None, gloves=None) -> dict:
    """Dataset numbers from per-episode stats: gloves (per layout and hand, or per `by` group), tasks, scenes."""
    if by is not None and by not in GROUPINGS:
        raise ArgumentError(f"--by must be one of {', '.join(GROUPINGS)}, got {by!r}")
    gloves = gloves if gloves is not None else (dataset_gloves(reader) if reader.episodes else {})
    accs: dict[tuple, dict] = {}
    healths: dict[tuple, dict] = {}
    nan_samples = []
    for ep, st in zip(reader.episodes, per_episode):
        nan_samples += st.get("nan_samples", [])
        for hand, h in st["hands"].items():
            key = _group_key(by, ep, hand, h["layout"])
            merge_hand(accs.setdefault(key, empty_hand(h["layout"])), h)
            merge_counts(healths.setdefault(key, {}), h["health"])
    groups = []
    for key in sorted(accs):
        row = dict(zip(_key_names(by), key))
        drift = drift_status(healths[key])
        if drift is not None:        # raw rows stored: said in words, also when short clips could not tell it
            healths[key]["drift"] = drift
        row.update(_glove_summary(accs[key], gloves, healths[key]))
        groups.append(row)
    return {"dataset": str(reader.root), "version": reader.version, "episodes": len(reader.episodes),
            "frames": len(reader), "contact_threshold": CONTACT_THRESHOLD, "by": by,
            "values": ("normalised [0,1] taxel values: from the stored raw rows under each episode's calibration "
                       "(exact; frames_from_raw) where the dataset has them, else the stored maps sampled at "
                       "taxel centres; raw_quantiles in raw glove units"),
            "gloves": groups, "tasks": _table(reader, "task"), "scenes": _table(reader, "scene"),
            "health_classes": list(CLASSES), "nan_samples": nan_samples,
            "contact_rules": sorted({g["contact_rule"] for g in groups if g.get("contact_rule")}),
            "scale": scale_suggestions(reader, per_episode)}


def _key_names(by: str | None) -> tuple:
    if by is None:
        return ("layout", "hand")
    if by in ("layout", "hand"):
        return (by,)
    return (by, "layout", "hand")


def _table(reader: DatasetReader, field: str) -> dict:
    table: dict[str, dict] = {}
    for pos, ep in enumerate(reader.episodes):
        _, n = reader.episode_range(pos)
        row = table.setdefault(ep[field], {"episodes": 0, "frames": 0, "duration_s": 0.0,
                                           "hands": {h: 0 for h in HANDS}})
        row["episodes"] += 1
        row["frames"] += n
        row["duration_s"] = round(row["duration_s"] + (n / ep["fps"] if ep.get("fps") else 0.0), 3)
        for hand in ep["hands"]:
            row["hands"][hand] += 1
    return dict(sorted(table.items()))


def dataset_stats(root, version: int | None = None, by: str | None = None, cache_dir="default",
                  progress: Progress | None = None) -> dict:
    """`htdata stats`: the summary of one version (default current), computing only uncached episodes."""
    cache = default_cache_dir(root) if cache_dir == "default" else cache_dir
    with DatasetReader(root, version=version) as reader:
        per_episode, info = episode_stats(reader, cache_dir=cache, progress=progress)
        out = summarise(reader, per_episode, by)
    out["cache"] = {"dir": str(cache) if cache is not None else None, **info}
    return out


def positive_value_quantile(root, q: float, version: int | None = None, cache_dir="default") -> float | None:
    """q-quantile of the positive taxel values of every glove of a version (None: no positive value)."""
    cache = default_cache_dir(root) if cache_dir == "default" else cache_dir
    with DatasetReader(root, version=version) as reader:
        per_episode, _ = episode_stats(reader, cache_dir=cache)
    hist = np.zeros(HIST_BINS, np.int64)
    for st in per_episode:
        for h in st["hands"].values():
            hist += np.asarray(h["hist"], np.int64)
    return quantile(0, hist, q)


def write_health_map(root, out, version: int | None = None, cache_dir="default") -> Path:
    """`htdata stats --health OUT.png`: the taxel health map of one version (htdata/inspect/healthmap.py)."""

    cache = default_cache_dir(root) if cache_dir == "default" else cache_dir
    with DatasetReader(root, version=version) as reader:
        per_episode, _ = episode_stats(reader, cache_dir=cache)
        pairs = sorted({(h["layout"], hand) for st in per_episode for hand, h in st["hands"].items()
                        if h["frames"]}, key=lambda p: (HANDS.index(p[1]), p[0]))
        return write_png(out, per_episode, dataset_gloves(reader) if pairs else {}, pairs)


def stats_benchmark(root) -> dict:
    """Frames/s of a cold stats run, a warm run (all cached) and the incremental run after one more episode.

    Uses a temporary cache (the dataset's own is neither read nor written):
    "before" = every episode but the last, computed cold, then again warm;
    "after" = all episodes with the cache of "before", i.e. what a version
    appending the last episode costs.
    """
    tmp = Path(tempfile.mkdtemp(prefix="htdata-stats-bench-"))
    try:
        with DatasetReader(root) as reader:
            n_ep = len(reader.episodes)
            if n_ep < 2:
                raise ArgumentError(f"{root}: the stats benchmark needs at least 2 episodes, found {n_ep}")
            before = list(range(n_ep - 1))
            frames_before = sum(reader.episode_range(p)[1] for p in before)
            runs = {}
            for name, positions in (("cold", before), ("warm", before), ("incremental", list(range(n_ep)))):
                t0 = time.perf_counter()
                per_episode, info = episode_stats(reader, positions, cache_dir=tmp)
                summarise(reader, per_episode, None)
                dt = time.perf_counter() - t0
                frames = frames_before if name != "incremental" else len(reader)
                hands = [h for st in per_episode for h in st["hands"].values()]
                runs[name] = {"seconds": round(dt, 4), "frames": frames, "frames_per_s": round(frames / dt, 1),
                              "episodes_computed": info["computed"], "frames_computed": info["frames_computed"],
                              "hand_frames": sum(h["frames"] for h in hands),
                              "hand_frames_from_raw": sum(h["frames"] for h in hands if h.get("values_from") == "raw")}
        return runs
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def cached_episode_stats(reader: DatasetReader, cache_dir=None) -> dict[int, dict]:
    """{episode position: stats} for the episodes whose entry is already cached (nothing is computed)."""
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir(reader.root)
    out = {}
    if cache is None or not cache.is_dir():
        return out
    for pos in range(len(reader.episodes)):
        entry = read_entry(cache / f"{episode_key(reader, pos)}.json")
        if entry is not None:
            out[pos] = entry
    return out


# its own names only: STATS_DIR is htdata.format.table's (tests/project/test_layering.py)
__all__ = ["STATS_SCHEMA", "GROUPINGS", "episode_key", "episode_stats", "summarise", "dataset_stats",
           "stats_benchmark", "cached_episode_stats", "write_health_map",
           "positive_value_quantile", "default_cache_dir"]
