"""Stored maps at the bound: how one EXR map member is written, measured side by side on real maps.

The codec table (codecs.py) picks the pixel type; this one asks what else the member's layout could
cost less with, for the maps the ingest stores by default (issue 26): compression RLE / ZIPS / ZIP /
PIZ; a data window around the covered pixels (display window 224x224, readers place the window:
htdata/format/tactilecodec.py, tests/format/test_exr_interop.py); half pixels where the exactness rule allows them;
three writers: htdata's own ZIP writer (htdata/format/exrzip.py: what the ingest writes, ISA-L deflate), the
OpenEXR binding (every other variant, and "_binding": its ZIP, libdeflate) and OpenImageIO's; and,
per variant but OpenImageIO's, the maps per second with the encode in 2 threads (both writers
release the GIL while they compress: htdata/ingest/encodepool.py uses it).

RULE (`pick_layout`): among the variants exact for every glove (max error below half of each glove's
quantisation step: the codec rule's test) and within `BYTES_BUDGET` of the smallest of those (the
issue asks for the bound "without paying for it": RLE is 4-18x the bytes of ZIP, which would multiply
the dataset for a fraction of a millisecond), the fastest single-thread encode (median of passes that
alternate the variants), where variants within `TIE` of the fastest count as equally fast, then the
smallest.

Imports inside functions: OpenImageIO (an optional reader/writer) only when its rows are measured.
"""

from __future__ import annotations

import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from htdata.format.tactilecodec import check_tactile_values, decode_exr, encode_exr
from htdata.glove.codecrule import ANALYTIC_MAX_ERROR

COMPRESSIONS = ("rle", "zips", "zip", "piz")
PIXELS = {"half": np.float16, "float": np.float32}
OIIO_COMPRESSIONS = ("rle", "zip")
TIE = 0.05
BYTES_BUDGET = 1.25
THREADS = 2
RULE = (f"exact for every glove (max error < half its quantisation step), at most {BYTES_BUDGET:g}x the bytes of "
        f"the smallest such variant, then the fastest single-thread encode (within {TIE:.0%} of the fastest "
        f"counts as a tie), then the smallest")


def _oiio_writer(compression: str, pixel: str):
    """encode(map) -> bytes through OpenImageIO's EXR writer (it writes files: one temp file, reused)."""
    import OpenImageIO as oiio

    tmp = Path(tempfile.mkdtemp(prefix="htdata-oiio-")) / "m.exr"

    def encode(tactile_map: np.ndarray) -> bytes:
        spec = oiio.ImageSpec(tactile_map.shape[1], tactile_map.shape[0], 1, pixel)
        spec.channelnames = ("Y",)
        spec.attribute("compression", compression)
        out = oiio.ImageOutput.create(str(tmp))
        # (H,W,C): a 2-D array is written transposed with garbage (TOOLING_FACTS)
        if out is None or not out.open(str(tmp), spec) or not out.write_image(tactile_map[..., None]):
            raise ValueError(f"OpenImageIO could not write an EXR: {oiio.geterror()}")
        out.close()
        return tmp.read_bytes()

    return encode


def variants() -> dict[str, dict]:
    """name -> {encode, pixel, compression, window, writer} of every measured layout."""
    out = {}
    for pixel, dtype in PIXELS.items():
        for comp in COMPRESSIONS:
            for window in (False, True):
                name = f"exr_{pixel}_{comp}" + ("_window" if window else "")
                writer = "htdata (exrzip.py)" if comp == "zip" and not window else "OpenEXR"
                out[name] = {"encode": (lambda m, c=comp, d=dtype, w=window: encode_exr(m, c, d, window=w)),
                             "pixel": pixel, "compression": comp, "window": window, "writer": writer}
        out[f"exr_{pixel}_zip_binding"] = {"encode": (lambda m, d=dtype: encode_exr(m, "zip", d, binding=True)),
                                           "pixel": pixel, "compression": "zip", "window": False, "writer": "OpenEXR"}
        for comp in OIIO_COMPRESSIONS:
            out[f"exr_{pixel}_{comp}_oiio"] = {"encode": _oiio_writer(comp, pixel), "pixel": pixel,
                                               "compression": comp, "window": False, "writer": "OpenImageIO"}
    return out


def _timed(encode, maps: np.ndarray, threads: int = 1) -> tuple[list[bytes], float]:
    t0 = time.perf_counter()
    if threads == 1:
        blobs = [encode(m) for m in maps]
    else:
        with ThreadPoolExecutor(threads) as pool:
            blobs = list(pool.map(encode, maps))
    return blobs, (time.perf_counter() - t0) * 1e3 / len(maps)


def layout_rows(maps: np.ndarray, reps: int = 3) -> list[dict]:
    """One row per variant over `maps` (N,224,224): bytes, encode ms (median of `reps` passes that alternate
    the variants, so load hits them alike; and with THREADS threads), max error against the float32 maps."""
    maps = np.stack([check_tactile_values(m, "layout bench") for m in maps])
    rows, times = {}, {}
    for rep in range(max(1, reps)):
        for name, v in variants().items():
            if name in rows and "error" in rows[name]:
                continue
            try:
                blobs, ms = _timed(v["encode"], maps)
            except (ImportError, ValueError) as exc:   # OpenImageIO missing or failing: say so, measure the rest
                rows[name] = {"layout": name, **{k: v[k] for k in ("pixel", "compression", "window", "writer")},
                              "error": str(exc)}
                continue
            times.setdefault(name, []).append(ms)
            if rep == 0:
                err = max(float(np.abs(decode_exr(b, name).astype(np.float64) - m).max()) for b, m in zip(blobs, maps))
                rows[name] = {"layout": name, **{k: v[k] for k in ("pixel", "compression", "window", "writer")},
                              "bytes_per_map": float(np.mean([len(b) for b in blobs])), "max_error": err,
                              "encode_ms_threads": (_timed(v["encode"], maps, THREADS)[1]
                                                    if v["writer"] != "OpenImageIO" else "n/a (one temp file)")}
    for name, ms in times.items():
        rows[name]["encode_ms"] = float(np.median(ms))
    return list(rows.values())


def is_exact(row: dict, steps: list[float | None]) -> bool:
    """The codec rule's test: max error below half of every glove's step (exact where a glove states none).

    The error is the larger of the measured one and the pixel type's analytic bound (codecrule): sample
    maps may miss the values where half rounds most (on the small corpus they all sat on half's grid)."""
    if "max_error" not in row:
        return False
    err = max(row["max_error"], ANALYTIC_MAX_ERROR[row["pixel"]])
    return all((err == 0.0) if s is None else err < s / 2 for s in steps)


def pick_layout(rows: list[dict], steps: list[float | None]) -> tuple[dict | None, str]:
    """(the row RULE picks for gloves of quantisation `steps`, why) from measured `rows`."""
    exact = [r for r in rows if is_exact(r, steps)]
    if not exact:
        return None, "no variant is exact for every glove"
    budget = min(r["bytes_per_map"] for r in exact) * BYTES_BUDGET
    over = [r["layout"] for r in exact if r["bytes_per_map"] > budget]
    exact = [r for r in exact if r["bytes_per_map"] <= budget]
    fastest = min(r["encode_ms"] for r in exact)
    tied = [r for r in exact if r["encode_ms"] <= fastest * (1 + TIE)]
    chosen = min(tied, key=lambda r: r["bytes_per_map"])
    slower = sorted((r for r in exact if r not in tied), key=lambda r: r["encode_ms"])
    why = (f"{len(exact) + len(over)} of {len(rows)} variants exact, {len(over)} of them over {budget / 1024:.1f} "
           f"KiB/map ({', '.join(over) or 'none'}); fastest of the rest {fastest:.3f} ms/map; within {TIE:.0%}: "
           f"{', '.join(_brief(r) for r in tied)}; smallest of those: {chosen['layout']}"
           + (f"; next slower: {_brief(slower[0])}" if slower else ""))
    return chosen, why


def _brief(row: dict) -> str:
    return f"{row['layout']} ({row['encode_ms']:.3f} ms, {row['bytes_per_map'] / 1024:.1f} KiB)"
