"""Tactile map codecs on real maps, and the stored error against each glove's quantisation step.

Maps are the sample corpus rasterised exactly as the ingest does (both
gloves), so sizes reflect real sparsity. A codec whose max error stays below
half a source step keeps every source level recoverable by rounding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.benchmarks.sources import discover, episode_maps
from htdata.codec import TACTILE_CODECS, codec_benchmark

# Source quantisation of each glove in [0,1] units (see pipelines/ and the layouts' value blocks).
GLOVE_STEPS = {"opentouch": 1.0 / 3072.0, "touchanything": 1.0 / 255.0}
DEFAULT_CODEC = "exr_half_zip"   # DEFAULT_CODEC_INFO: EXR half, ZIP


def real_maps(corpus: Path, adapter_name: str, max_maps: int) -> np.ndarray:
    """Up to `max_maps` rasterised maps spread evenly over the adapter's episodes and hands."""
    cfg, adapter, refs = discover(adapter_name, corpus / adapter_name)
    per_ep = max(1, -(-max_maps // max(len(refs), 1)))
    chosen, rasters = [], {}
    for ref in refs:
        em = episode_maps(cfg, adapter, ref, rasters)
        for maps in em.maps.values():
            take = np.linspace(0, len(maps) - 1, num=min(per_ep, len(maps))).round().astype(int)
            chosen.append(maps[np.unique(take)])
        if sum(len(c) for c in chosen) >= max_maps:
            break
    if not chosen:
        raise ValueError(f"{corpus / adapter_name}: no episode gave a tactile map")
    return np.concatenate(chosen)[:max_maps]


def codec_rows(maps_by_glove: dict[str, np.ndarray]) -> dict:
    """Codec table over all gloves' maps, plus per-glove error margins of every codec."""
    all_maps = np.concatenate(list(maps_by_glove.values()))
    rows = codec_benchmark(all_maps)
    by_codec = {r["codec"]: r for r in rows}
    margins = []
    for glove, maps in maps_by_glove.items():
        step = GLOVE_STEPS[glove]
        for r in codec_benchmark(maps):
            margins.append({"glove": glove, "codec": r["codec"], "maps": int(len(maps)),
                            "step": step, "max_error": r["max_error"],
                            # None = exact (no error to divide by): rendered as "exact", kept valid JSON
                            "step_over_max_error": step / r["max_error"] if r["max_error"] > 0 else None,
                            "levels_recoverable": bool(r["max_error"] < step / 2)})
    sparsity = float(np.mean(all_maps == 0))
    lossless = [r for r in rows if not r["codec"].endswith("lossy")]
    smallest = min(lossless, key=lambda r: r["bytes_per_frame"])
    d = by_codec[DEFAULT_CODEC]
    reason = (f"{DEFAULT_CODEC}: {d['bytes_per_frame'] / 1024:.1f} KiB/frame "
              f"({d['bytes_per_frame'] / by_codec['exr_float_zip']['bytes_per_frame']:.2f}x of float ZIP), "
              f"encode {d['encode_ms']:.2f} ms, decode {d['decode_ms']:.2f} ms, max error {d['max_error']:.2e}; "
              f"smallest lossless here: {smallest['codec']} ({smallest['bytes_per_frame'] / 1024:.1f} KiB)")
    return {"maps": int(len(all_maps)), "zero_fraction": sparsity, "rows": rows, "margins": margins,
            "default": DEFAULT_CODEC, "reason": reason, "codecs": list(TACTILE_CODECS)}
