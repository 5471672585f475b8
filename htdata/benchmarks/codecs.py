"""Tactile map codecs on real maps, and the stored error against each glove's quantisation step.

Maps are the sample corpus rasterised exactly as the ingest does (every
glove layout the corpus uses), so sizes reflect real sparsity. A codec whose max error stays below
half a source step keeps every source level recoverable by rounding; the
default is the smallest EXR codec doing so for every glove (htdata/glove/codecrule.py),
computed from the measured table, not written by hand.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from htdata.benchmarks.maplayouts import RULE as LAYOUT_RULE
from htdata.benchmarks.maplayouts import layout_rows, pick_layout
from htdata.benchmarks.sources import discover, episode_maps
from htdata.errors import ArgumentError
from htdata.format.canvas import MAP_SHAPE
from htdata.format.tactilecodec import check_tactile_values, decode_exr, decode_png16, encode_exr, encode_png16
from htdata.format.tactilesettings import TactileConfig
from htdata.glove.codecrule import RULE, GloveStep, glove_step, pick_codec, resolve_codec
from htdata.glove.layouts import Layout, load_layout


# Candidates of the codec rule (EXR: what the dataset member can store) and, for comparison, other formats.
def _exr_codec(compression: str, pixel_type) -> tuple[Callable, Callable]:
    """(encode, decode) of an EXR variant; encode applies the dataset value rule first."""
    def encode(tactile_map: np.ndarray) -> bytes:
        return encode_exr(check_tactile_values(tactile_map, f"exr {compression}"), compression, pixel_type)

    return encode, decode_exr


LAYOUT_MAPS = 96      # maps the layout table encodes (x 20 variants x 3 passes)

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


def source_step(layout: Layout) -> GloveStep:
    """One source quantisation level of a glove in [0,1] map units (its layout's value block; see codecrule)."""
    return glove_step(layout)


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
        raise ArgumentError(f"{corpus}: no episode of {list(sources)} gave a tactile map")
    return {layout_id: np.concatenate(parts)[:max_maps] for layout_id, parts in sorted(chosen.items())}


def codec_rows(maps_by_layout: dict[str, np.ndarray], compression: str | None = None) -> dict:
    """Codec table over all gloves' maps, each glove's error margin per codec, and the default by the rule.

    "default" is what `codecrule.pick_codec` picks from the measured rows for
    a dataset holding every glove here (the strictest wins); "code_default" is
    what the ingest's `[codec] tactile = "auto"` resolves to for the same
    gloves at `compression` (analytic errors): the two must agree. A
    codec's error is its max over ALL maps (a glove's few maps may miss the
    values where float16 rounds most); the margin rows show each glove's own.
    """

    compression = compression or TactileConfig().compression      # the pipelines' default
    all_maps = np.concatenate(list(maps_by_layout.values()))
    rows = codec_benchmark(all_maps)
    gloves = {layout_id: source_step(load_layout(layout_id)) for layout_id in maps_by_layout}
    margins, per_glove = [], {}
    for layout_id, maps in maps_by_layout.items():
        g = gloves[layout_id]
        glove_rows = codec_benchmark(maps)
        for r in glove_rows:
            margins.append({"layout": layout_id, "codec": r["codec"], "maps": int(len(maps)),
                            "step": g.step, "step_from": g.source, "max_error": r["max_error"],
                            # None = exact (no error to divide by): rendered as "exact", kept valid JSON
                            "step_over_max_error": (g.step / r["max_error"]
                                                    if g.step is not None and r["max_error"] > 0 else None),
                            "levels_recoverable": g.keeps_levels(r["max_error"])})
        # The rule takes each codec's error over ALL maps: any glove's map may hold any value in [0,1].
        per_glove[layout_id] = (pick_codec([g], rows)[0] or {}).get("codec")
    chosen, why = pick_codec(list(gloves.values()), rows)
    code = resolve_codec("auto", compression, list(gloves.values()))
    by_codec = {r["codec"]: r for r in rows}
    d = by_codec[chosen["codec"]] if chosen else None
    lossless = sorted((r for r in rows if r["max_error"] == 0), key=lambda r: r["bytes_per_frame"])
    reason = (f"rule: {RULE}. Measured: {why}"
              + (f"; {d['bytes_per_frame'] / 1024:.1f} KiB/frame, encode {d['encode_ms']:.2f} ms, "
                 f"decode {d['decode_ms']:.2f} ms" if d else "")
              + f". Per glove alone: {', '.join(f'{k} -> {v}' for k, v in per_glove.items())}"
              + f". Smallest exact codec: {lossless[0]['codec'] if lossless else 'none'}"
              + f". The ingest's [codec] tactile = \"auto\" (analytic errors) picks {code.codec}: "
              + ("the same" if chosen and code.codec == chosen["codec"] else "DIFFERENT"))
    return {"maps": int(len(all_maps)), "zero_fraction": float(np.mean(all_maps == 0)), "rows": rows,
            "margins": margins, "default": chosen["codec"] if chosen else None, "code_default": code.codec,
            "per_glove": per_glove, "reason": reason, "codecs": list(TACTILE_CODECS),
            **layout_section(all_maps, gloves, code.codec)}


def layout_section(all_maps: np.ndarray, gloves: dict[str, GloveStep], ingest_codec: str) -> dict:
    """The stored-map layout table (maplayouts.py) on up to LAYOUT_MAPS of the maps, its pick for the
    dataset's gloves and for each glove alone, and what the ingest writes (`ingest_codec`, full canvas,
    htdata's ZIP writer, in encodepool's threads)."""
    take = np.linspace(0, len(all_maps) - 1, num=min(LAYOUT_MAPS, len(all_maps))).round().astype(int)
    rows = layout_rows(all_maps[np.unique(take)])
    chosen, why = pick_layout(rows, [g.step for g in gloves.values()])
    return {"layouts": rows, "layout_rule": LAYOUT_RULE, "layout_default": chosen["layout"] if chosen else None,
            "layout_reason": why, "ingest_layout": ingest_codec,
            "layout_per_glove": {lid: (pick_layout(rows, [g.step])[0] or {}).get("layout") for lid, g in gloves.items()}}
