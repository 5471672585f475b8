"""What keeping every raw glove row costs, and what rendering maps from raw rows gains.

- Per adapter: the same sample episodes ingested with `[tactile] keep_raw`
  on and off, alternating (1 worker, `reps` runs each, medians): frames/s
  with raw over frames/s without (target >= 0.9), bytes per sample the raw
  members add, and glove rows stored per sample (a 100 Hz glove beside
  30 Hz video stores ~3; nothing of the recording is left out).
- Loader: the map of each sample from its stored EXR vs rendered from its
  paired raw row (htdata.read.rawstream.RawMapRenderer, nearest mode): frames/s
  of both, and the largest difference (the map codec's rounding).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from htdata.benchmarks.ingest import ingest_run
from htdata.benchmarks.tables import table
from htdata.format.table import HANDS, SIZE_FIELDS, raw_member, tactile_member
from htdata.format.tactilecodec import decode_tactile
from htdata.read.rawstream import RawMapRenderer
from htdata.read.reader import DatasetReader
from htdata.store.manifest import load_index

TARGET_RATIO = 0.9


def storage_row(name: str, root: Path, work: Path, reps: int) -> dict:
    """One adapter: keep_raw on vs off, alternating runs, medians."""


    times = {True: [], False: []}
    frames = 0
    for _ in range(reps):
        for keep in (False, True):
            run = ingest_run([(name, root)], work / f"raw_{name}_{keep}", 1,
                             (f"tactile.keep_raw={'true' if keep else 'false'}", "tactile.maps=stored"))
            times[keep].append(run["wall_s"])
            frames = run["frames"]
    with_raw = work / f"raw_{name}_True"
    rows = load_index(with_raw)
    raw_bytes = sum(int(rows[SIZE_FIELDS[raw_member(h)]].sum()) for h in HANDS)
    reader = DatasetReader(with_raw)
    stored = 0
    for i in range(len(reader)):
        meta = reader.decoded(i, ("json",))["meta"]
        stored += sum(len(v) for v in meta.get("raw_row", {}).values())
    hand_samples = sum(int((rows[SIZE_FIELDS[tactile_member(h)]] > 0).sum()) for h in HANDS)
    on, off = statistics.median(times[True]), statistics.median(times[False])
    return {"adapter": name, "samples": frames, "reps": reps, "seconds_without_raw": off, "seconds_with_raw": on,
            "frames_per_s_without_raw": frames / off, "frames_per_s_with_raw": frames / on,
            "ratio_with_over_without": off / on, "raw_bytes_per_sample": raw_bytes / max(frames, 1),
            "glove_rows_per_hand_sample": stored / max(hand_samples, 1)}


def map_path_row(dataset: Path, limit: int) -> dict:
    """Stored EXR decode vs rendering from raw rows, over the same hand samples."""

    reader = DatasetReader(dataset)
    renderer = RawMapRenderer(reader)
    items = [(i, h) for i in range(len(reader)) for h in HANDS
             if reader.index[i][SIZE_FIELDS[raw_member(h)]] > 0 and reader.index[i][SIZE_FIELDS[tactile_member(h)]] > 0]
    items = items[:limit]
    t0 = time.perf_counter()
    stored = [decode_tactile(reader.sample(i, (tactile_member(h),))[tactile_member(h)]) for i, h in items]
    t1 = time.perf_counter()
    rendered = [renderer.sample_map(i, h) for i, h in items]
    t2 = time.perf_counter()
    diff = max((float(np.abs(a - b).max()) for a, b in zip(stored, rendered)), default=0.0)
    return {"maps": len(items), "stored_exr_frames_per_s": len(items) / (t1 - t0),
            "raw_render_frames_per_s": len(items) / (t2 - t1), "raw_over_stored": (t1 - t0) / (t2 - t1),
            "max_abs_difference": diff, "raster_mode": reader.manifest["codec"]["tactile"].get("raster_mode")}


def raw_rows(corpus: Path, work: Path, adapters: tuple[str, ...], dataset: Path, quick: bool) -> dict:
    reps = 1 if quick else 2
    storage = [storage_row(name, corpus / name, work, reps) for name in adapters]
    return {"storage": storage, "maps": map_path_row(dataset, 200 if quick else 2000),
            "target_ratio": TARGET_RATIO,
            "target_met": all(r["ratio_with_over_without"] >= TARGET_RATIO for r in storage)}


def raw_markdown(d: dict) -> list[str]:

    lines = table(d["storage"], [("adapter", "adapter"), ("samples", "samples"),
                                 ("frames_per_s_without_raw", "frames/s, maps only"),
                                 ("frames_per_s_with_raw", "frames/s, + raw rows"),
                                 ("ratio_with_over_without", "ratio"),
                                 ("raw_bytes_per_sample", "raw bytes/sample"),
                                 ("glove_rows_per_hand_sample", "glove rows per hand sample")])
    met = "met" if d["target_met"] else "NOT met"
    m = d["maps"]
    lines += [f"Ingest with every raw row / without (median of alternating runs, 1 worker): target >= "
              f"{d['target_ratio']} for every adapter: {met}.", ""]
    lines += table([m], [("maps", "maps"), ("stored_exr_frames_per_s", "stored EXR decode, maps/s"),
                         ("raw_render_frames_per_s", "rendered from raw rows, maps/s"),
                         ("raw_over_stored", "raw / EXR speed"), ("max_abs_difference", "max |difference|"),
                         ("raster_mode", "raster mode")])
    faster = "faster" if m["raw_over_stored"] >= 1 else "slower"
    same = ("identical to the stored maps (this dataset stores float maps)" if m["max_abs_difference"] == 0 else
            "exact, the stored maps differing by the map codec's rounding")
    return lines + [f"Rendering from raw rows is {faster} ({m['raw_over_stored']:.2f}x) and, in nearest mode, {same}: "
                    f"the torch loaders' default `maps_from=\"best\"` renders from raw rows when a dataset has them "
                    f"and was rasterised in nearest mode.", ""]
