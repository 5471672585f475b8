"""Where a glove-only ingest's time goes when it stores its maps, and what would reach stored >= 0.8x raw (issue 47).

The glove-only rows of the maps section (maps.py `glove_only_row`) time the same recording ingested with
maps stored and with `maps = "raw"`. This module takes the stored dataset's own maps (as stored: the
pixels the ingest encoded) and times, per map, in this process, on one thread (CPU seconds, the least of
`reps` passes):
- `encode`: `encode_tactile` as the ingest calls it (value rule + htdata/format/exrzip.py);
- `deflate`: only ISA-L's deflate of the map's non-zero chunks at the writer's level (`DEFLATE_LEVEL`),
  the bytes the file holds: the part of the encode no rewrite of the Python around it removes;
- `level0`: the same chunks at ISA-L level 0 (any inflater reads it: the same pixels, other bytes),
  and the chunk bytes at both levels.

From them and the ingest's own medians, per frame (`projections`, seconds per frame: raw R, stored S,
the stored ingest's encode wait E and rasterise Z, k maps per frame):
- `ceiling_one_core` = R / (R + k deflate + Z): the best stored / raw ratio on one core with today's
  bytes, were the rest of storing a map (filter, header, value rule, members, spool) free;
- `level0_one_core` = R / (S - k (deflate - level0)): today's ingest with level-0 streams;
- `spare_core` = R / (S - E): the encode wholly off the worker's path (another core), the upper
  bound of moving it to a helper process (the maps' transfer not counted).
"""

from __future__ import annotations

import time

import numpy as np
from isal import isal_zlib

from htdata.benchmarks.tables import table
from htdata.format.exrzip import DEFLATE_LEVEL, LINES_PER_CHUNK, zip_filter
from htdata.format.table import HANDS, tactile_member
from htdata.format.tactilecodec import decode_exr_pixels, encode_tactile
from htdata.read.reader import DatasetReader

TARGET = 0.8      # issue 47: stored >= 0.8x the maps = "raw" speed
MAP_MEMBERS = tuple(tactile_member(h) for h in HANDS)


def stored_maps(root, limit: int | None = None) -> list[np.ndarray]:
    """The dataset's maps as stored (float16 or float32 pixels, as the ingest encoded them), sample order."""
    maps = []
    with DatasetReader(root) as reader:
        for i, members in reader.iter_samples(decode=False, suffixes=MAP_MEMBERS):
            maps += [decode_exr_pixels(data, f"sample {i}") for _, data in sorted(members.items())]
            if limit is not None and len(maps) >= limit:
                break
    return maps


def _filtered_chunks(pixels: np.ndarray) -> list[np.ndarray]:
    """The ZIP-filtered non-zero 16-line chunks of a map (a 224-line map has no partial chunk)."""
    words = np.ascontiguousarray(pixels).view(np.uint16).reshape(pixels.shape[0] // LINES_PER_CHUNK, -1)
    return list(zip_filter(words[np.flatnonzero(words.any(axis=1))]))


def _cpu_us_per_map(fn, count: int, reps: int) -> float:
    best = float("inf")
    for _ in range(max(1, reps)):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return 1e6 * best / max(count, 1)


def encode_costs(maps: list[np.ndarray], pixel_type: str, reps: int = 3) -> dict:
    """CPU microseconds per map of the whole encode and of its deflate alone (levels DEFLATE_LEVEL and 0),
    chunk bytes per map at both levels, non-zero chunks per map (module docstring)."""
    chunks = [c for m in maps for c in _filtered_chunks(m)]
    n = len(maps)
    out = {"maps": n, "pixel_type": pixel_type, "nonzero_chunks_per_map": len(chunks) / max(n, 1),
           "deflate_level": DEFLATE_LEVEL}
    out["encode_us"] = _cpu_us_per_map(lambda: [encode_tactile(m, "zip", pixel_type=pixel_type) for m in maps], n, reps)
    for key, level in (("deflate", DEFLATE_LEVEL), ("level0", 0)):
        out[f"{key}_us"] = _cpu_us_per_map(lambda: [isal_zlib.compress(c, level) for c in chunks], n, reps)
        out[f"{key}_bytes"] = sum(len(isal_zlib.compress(c, level)) for c in chunks) / max(n, 1)
    out["deflate_share_of_encode"] = out["deflate_us"] / out["encode_us"] if out["encode_us"] else 0.0
    return out


def projections(row: dict, costs: dict) -> dict:
    """Per-frame seconds of the two ingests (medians of the glove-only row) and the ratios of the module
    docstring; `maps_per_frame` from the stored dataset's map count."""
    frames = max(row["frames"], 1)
    raw_s, stored_s = 1.0 / row["frames_per_s_raw"], 1.0 / row["frames_per_s_stored"]
    k = costs["maps"] / frames
    encode_s, raster_s = row["encode_s_stored"] / frames, row["rasterise_s_stored"] / frames
    d1, d0 = 1e-6 * costs["deflate_us"], 1e-6 * costs["level0_us"]
    return {"maps_per_frame": k, "raw_ms_per_frame": 1e3 * raw_s, "stored_ms_per_frame": 1e3 * stored_s,
            "encode_wait_ms_per_frame": 1e3 * encode_s, "rasterise_ms_per_frame": 1e3 * raster_s,
            "deflate_ms_per_frame": 1e3 * k * d1, "budget_ms_per_frame": 1e3 * raw_s * (1 / TARGET - 1),
            "ceiling_one_core": raw_s / (raw_s + k * d1 + raster_s),
            "level0_one_core": raw_s / max(stored_s - k * (d1 - d0), raw_s * 1e-3),
            "level0_bytes_ratio": costs["level0_bytes"] / max(costs["deflate_bytes"], 1e-9),
            "spare_core": raw_s / max(stored_s - encode_s, raw_s * 1e-3)}


def glove_cost_markdown(rows: list[dict]) -> list[str]:
    """The per-frame cost table and the projected ratios of the glove-only rows (module docstring)."""
    if not rows:
        return []
    cells = [{"recording": r["recording"].split(" (")[0], **r["costs"], **r["projections"],
              "measured": r["speed_ratio"]} for r in rows]
    lines = [f"Where storing the maps goes, per frame (ms; the ingest's medians; per-map CPU on the stored dataset's "
             f"own maps, one thread, least of the passes: htdata/benchmarks/mapcost.py). Budget = what 0.8x allows "
             f"a stored frame beyond a raw one; deflate = ISA-L level {DEFLATE_LEVEL} of the maps' non-zero chunks "
             f"alone, the bytes the files hold:", ""]
    lines += table(cells, [("recording", "recording"), ("raw_ms_per_frame", "raw ms/frame"),
                           ("stored_ms_per_frame", "stored ms/frame"), ("budget_ms_per_frame", "budget ms/frame"),
                           ("encode_wait_ms_per_frame", "encode wait"), ("rasterise_ms_per_frame", "rasterise"),
                           ("maps_per_frame", "maps/frame"), ("nonzero_chunks_per_map", "deflated chunks/map"),
                           ("encode_us", "encode us/map"), ("deflate_us", "deflate us/map"),
                           ("deflate_ms_per_frame", "deflate ms/frame"), ("level0_us", "level-0 us/map"),
                           ("deflate_bytes", "B/map"), ("level0_bytes", "level-0 B/map")])
    lines += ["Stored / raw: measured, and projected (module docstring): one core with today's bytes if only the "
              "deflate and the rasterise were left (the ceiling), today's ingest with level-0 deflate streams "
              "(the same pixels, more bytes), the encode wholly on a spare core:", ""]
    lines += table(cells, [("recording", "recording"), ("measured", "measured"),
                           ("ceiling_one_core", "ceiling, one core, today's bytes"),
                           ("level0_one_core", "level 0, one core"), ("level0_bytes_ratio", "level-0 map bytes x"),
                           ("spare_core", "encode on a spare core")])
    return lines
