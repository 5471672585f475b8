"""Tactile map codecs on real maps, and the stored error against each glove's quantisation step.

Maps are the sample corpus rasterised exactly as the ingest does (every
glove layout the corpus uses), so sizes reflect real sparsity. A codec whose max error stays below
half a source step keeps every source level recoverable by rounding.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from htdata.benchmarks.sources import discover, episode_maps
from htdata.codec import check_tactile_values, decode_exr, decode_png16, encode_exr, encode_png16
from htdata.format import MAP_SHAPE
from htdata.layouts import Layout, load_layout

# Alternatives measured against the dataset's codec (EXR half ZIP, codec.DEFAULT_CODEC_INFO).
def _exr_codec(compression: str, pixel_type) -> tuple[Callable, Callable]:
    """(encode, decode) of an EXR variant; encode applies the dataset value rule first."""
    def encode(tactile_map: np.ndarray) -> bytes:
        return encode_exr(check_tactile_values(tactile_map, f"exr {compression}"), compression, pixel_type)

    return encode, decode_exr


TACTILE_CODECS: dict[str, tuple[Callable[[np.ndarray], bytes], Callable[[bytes], np.ndarray]]] = {
    "exr_half_zip": _exr_codec("zip", np.float16),
    "exr_half_piz": _exr_codec("piz", np.float16),
    "exr_half_htj2k256": _exr_codec("htj2k256", np.float16),
    "exr_float_zip": _exr_codec("zip", np.float32),
    "png16": (encode_png16, decode_png16),
    "exr_half_dwab_lossy": _exr_codec("dwab", np.float16),
}



def codec_benchmark(maps: np.ndarray, codecs: dict | None = None) -> list[dict]:
    """Size, speed and error of each tactile codec over `maps` (N,224,224) in [0,1].

    Returns one dict per codec: bytes_per_frame, encode_ms, decode_ms (per
    frame, mean), max_error, rmse. Timing only; callers must not assert on it.
    """
    maps = np.asarray(maps, dtype=np.float32)
    if maps.ndim != 3 or maps.shape[1:] != MAP_SHAPE or len(maps) == 0:
        raise ValueError(f"codec_benchmark needs (N,224,224) maps with N>0, got {maps.shape}")
    results = []
    for name, (encode, decode) in (codecs or TACTILE_CODECS).items():
        t0 = time.perf_counter()
        blobs = [encode(m) for m in maps]
        t1 = time.perf_counter()
        decoded = np.stack([decode(b) for b in blobs])
        t2 = time.perf_counter()
        err = decoded.astype(np.float64) - maps
        results.append({
            "codec": name,
            "bytes_per_frame": float(np.mean([len(b) for b in blobs])),
            "encode_ms": (t1 - t0) * 1e3 / len(maps),
            "decode_ms": (t2 - t1) * 1e3 / len(maps),
            "max_error": float(np.abs(err).max()),
            "rmse": float(np.sqrt(np.mean(err ** 2))),
        })
    return results


DEFAULT_CODEC = "exr_half_zip"   # DEFAULT_CODEC_INFO: EXR half, ZIP
DIRECT_SOURCE_LEVELS = 255       # see source_step


def source_step(layout: Layout) -> tuple[float, str]:
    """One source quantisation level of a glove in [0,1] units, and where the number comes from.

    An "inverted" glove counts integer firmware units 0..max, so its value
    block gives the step (1/max). A "direct" glove delivers [0, max] floats
    and its value block does not state their resolution: the only shipped one,
    TouchAnything, computes them from uint8 sensor bytes (SOURCE_FORMATS.md,
    jq_pressure.json), so 8 bits is assumed, and the row says so.
    """
    if layout.value["convention"] == "inverted":
        return 1.0 / float(layout.value["max"]), "value block (integer units)"
    return 1.0 / DIRECT_SOURCE_LEVELS, f"assumed {DIRECT_SOURCE_LEVELS} levels (direct values)"


def real_maps(corpus: Path, sources: tuple[str, ...], max_maps: int) -> dict[str, np.ndarray]:
    """layout id -> up to `max_maps` rasterised maps, spread evenly over each source's episodes and hands.

    `sources` are corpus folders named like their shipped pipeline; an episode
    whose layouts all have `max_maps` maps already is not read.
    """
    chosen: dict[str, list[np.ndarray]] = {}

    def full(layout_id: str) -> bool:
        return sum(len(c) for c in chosen.get(layout_id, [])) >= max_maps

    for source in sources:
        cfg, adapter, refs = discover(source, corpus / source)
        per_ep = max(1, -(-max_maps // max(len(refs), 1)))
        for ref in refs:
            if all(full(layout_id) for layout_id in ref.layouts.values()):
                continue
            em = episode_maps(cfg, adapter, ref)
            for hand, maps in em.maps.items():
                if len(maps) and not full(em.layouts[hand]):
                    take = np.linspace(0, len(maps) - 1, num=min(per_ep, len(maps))).round().astype(int)
                    chosen.setdefault(em.layouts[hand], []).append(maps[np.unique(take)])
    if not chosen:
        raise ValueError(f"{corpus}: no episode of {list(sources)} gave a tactile map")
    return {layout_id: np.concatenate(parts)[:max_maps] for layout_id, parts in sorted(chosen.items())}


def codec_rows(maps_by_layout: dict[str, np.ndarray]) -> dict:
    """Codec table over all gloves' maps, plus each glove layout's error margin for every codec."""
    all_maps = np.concatenate(list(maps_by_layout.values()))
    rows = codec_benchmark(all_maps)
    by_codec = {r["codec"]: r for r in rows}
    margins = []
    for layout_id, maps in maps_by_layout.items():
        step, step_from = source_step(load_layout(layout_id))
        for r in codec_benchmark(maps):
            margins.append({"layout": layout_id, "codec": r["codec"], "maps": int(len(maps)),
                            "step": step, "step_from": step_from, "max_error": r["max_error"],
                            # None = exact (no error to divide by): rendered as "exact", kept valid JSON
                            "step_over_max_error": step / r["max_error"] if r["max_error"] > 0 else None,
                            "levels_recoverable": bool(r["max_error"] < step / 2)})
    sparsity = float(np.mean(all_maps == 0))
    lossless = [r for r in rows if r["max_error"] == 0]          # lossless means exact, nothing less
    smallest = min(lossless, key=lambda r: r["bytes_per_frame"]) if lossless else None
    keeps_all = [r for r in rows if all(m["levels_recoverable"] for m in margins if m["codec"] == r["codec"])]
    by_rule = min(keeps_all, key=lambda r: r["bytes_per_frame"]) if keeps_all else None
    d = by_codec[DEFAULT_CODEC]
    lost = sorted(m["layout"] for m in margins if m["codec"] == DEFAULT_CODEC and not m["levels_recoverable"])
    exact = f"{smallest['codec']} ({smallest['bytes_per_frame'] / 1024:.1f} KiB)" if smallest else "none"
    reason = (f"{DEFAULT_CODEC}: {d['bytes_per_frame'] / 1024:.1f} KiB/frame "
              f"({d['bytes_per_frame'] / by_codec['exr_float_zip']['bytes_per_frame']:.2f}x of float ZIP), "
              f"encode {d['encode_ms']:.2f} ms, decode {d['decode_ms']:.2f} ms, max error {d['max_error']:.2e} "
              f"(not lossless; source levels NOT recoverable for: {', '.join(lost) or 'none'}); "
              f"smallest exact codec: {exact}; the rule 'smallest codec keeping every glove's levels "
              f"(max error < step/2)' would pick {by_rule['codec'] if by_rule else 'none'}")
    return {"maps": int(len(all_maps)), "zero_fraction": sparsity, "rows": rows, "margins": margins,
            "default": DEFAULT_CODEC, "reason": reason, "codecs": list(TACTILE_CODECS)}
