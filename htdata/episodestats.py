"""Per-episode tactile statistics: one pass over an episode's tactile members, mergeable results.

`compute_episode(reader, pos, gloves)` reads only the episode's tactile
members (never the JPEG), samples every stored map at its glove's taxel
centres (`Rasteriser(layout).sample`) and returns, per hand, the mergeable
sums `merge_hand` adds up: frames, contact frames, per-taxel count / sum /
sum of squares, per-region contact frames and pressure sums, a fixed-bin
histogram of the values (plus exact zeros and the max), the per-frame max
(what `htdata trim --idle` needs) and the taxel health
(htdata/health.py). A map holding NaN/Inf is left out and named in
"nan_samples" (episode, frame, hand, key).

Values are the NORMALISED values of the stored maps sampled at taxel
centres: until raw glove values are stored (issue #11) raw-unit quantiles
are not available.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from htdata.codec import decode_exr_pixels
from htdata.format import HANDS, MAP_SHAPE, tactile_member
from htdata.health import TaxelGrid, classify
from htdata.layouts import CanonicalHand, Layout, parse_canonical, parse_layout
from htdata.rasterise import Rasteriser

CONTACT_THRESHOLD = 0.02      # a taxel above this is in contact (validate's contact threshold)
HIST_BINS = 1000              # fixed bins over (0, 1]: quantiles to 0.001, mergeable by addition
CHUNK = 64                    # maps sampled per sparse product (bounds memory: 64 x 50176 float64)


def value_histogram(values: np.ndarray) -> tuple[int, np.ndarray]:
    """(count of exact zeros, HIST_BINS counts of the positive values; 1.0 in the last bin)."""
    v = values[values > 0]
    bins = np.minimum((v * HIST_BINS).astype(np.intp), HIST_BINS - 1)
    return int(values.size - v.size), np.bincount(bins, minlength=HIST_BINS)


def quantile(zeros: int, hist: np.ndarray, q: float) -> float | None:
    """q-quantile from (zeros, histogram), linear inside the bin; None when empty."""
    total = zeros + int(hist.sum())
    if total == 0:
        return None
    rank = q * (total - 1) + 1          # 1-based rank of the wanted value
    if rank <= zeros:
        return 0.0
    cum = zeros + np.cumsum(hist)
    b = int(np.searchsorted(cum, rank))
    before = cum[b - 1] if b else zeros
    inside = (rank - before) / max(int(hist[b]), 1)
    return float((b + min(max(inside, 0.0), 1.0)) / HIST_BINS)


@dataclass
class Glove:
    """One layout of the dataset: parsed geometry, sampler and taxel -> region names."""
    layout: Layout
    canonical: CanonicalHand

    @cached_property
    def rasteriser(self) -> Rasteriser:
        return Rasteriser(self.layout, canonical=self.canonical)

    @cached_property
    def taxels(self) -> TaxelGrid:
        return TaxelGrid.of(self.layout)

    @cached_property
    def regions(self) -> list[str]:
        """Canonical place name of each live taxel (the place most of its rendered pixels fall in)."""
        names = {v: k for k, v in self.canonical.region_ids.items()}
        m = self.rasteriser.matrix
        place = self.canonical.region_map.ravel()
        out = []
        for cell in self.rasteriser.live_index:
            pix = m.indices[m.indptr[cell]:m.indptr[cell + 1]]
            ids = place[pix][place[pix] > 0]
            out.append(names[int(np.bincount(ids).argmax())] if ids.size else "outside")
        return out


def dataset_gloves(reader) -> dict[str, Glove]:
    """layout id -> Glove, from the dataset's own layout and canonical documents."""
    canon_file = reader.manifest["canonical"]["file"]
    from htdata import storage
    canonical = parse_canonical(json.loads(storage.read_text(storage.join(reader.root, canon_file))),
                                f"{reader.root}/{canon_file}")
    gloves = {}
    for layout_id, entry in reader.manifest["layouts"].items():
        where = f"{reader.root}/{entry['file']}"
        try:
            layout = parse_layout(reader.layout(layout_id), where, canonical=canonical)
        except (ValueError, KeyError) as exc:
            raise ValueError(f"{where}: layout {layout_id!r} is not a glove layout the stats can sample "
                             f"taxels from: {exc}") from exc
        gloves[layout_id] = Glove(layout, canonical)
    return gloves


def compute_episode(reader, pos: int, gloves: dict[str, Glove]) -> dict:
    """Stats of episode `pos` of `reader` (see the module docstring); JSON-ready."""
    ep = reader.episodes[pos]
    first, n = reader.episode_range(pos)
    hands = [h for h in HANDS if h in ep["layouts"]]
    suffixes = tuple(tactile_member(h) for h in hands)
    series: dict[str, list[np.ndarray]] = {h: [] for h in hands}
    frames: dict[str, list[int]] = {h: [] for h in hands}
    nan_samples = []
    pending: dict[str, list] = {h: [] for h in hands}

    def flush(hand: str) -> None:
        if pending[hand]:
            taxels = gloves[ep["layouts"][hand]].rasteriser.sample(np.stack(pending[hand]))
            live = gloves[ep["layouts"][hand]].layout.live_mask
            series[hand].append(taxels[:, live])
            pending[hand].clear()

    for i in range(first, first + n):
        _, key, members = reader.read_sample(i, suffixes)
        frame = i - first
        for hand in hands:
            data = members.get(tactile_member(hand))
            if data is None:
                continue
            where = f"{reader.root}: {key}.{tactile_member(hand)}"
            tmap = decode_exr_pixels(data, where)     # half as stored: one conversion, in sample()
            if tmap.shape != MAP_SHAPE:
                raise ValueError(f"{where}: decoded tactile map has shape {tmap.shape}, expected {MAP_SHAPE}")
            bad = ~np.isfinite(tmap)
            if bad.any():
                nan_samples.append({"episode": ep["episode_id"], "frame": frame, "hand": hand, "key": key,
                                    "sample": i, "nonfinite_pixels": int(bad.sum())})
                continue
            pending[hand].append(tmap)
            frames[hand].append(frame)
            if len(pending[hand]) >= CHUNK:
                flush(hand)
    out = {"episode_id": ep["episode_id"], "frames": n, "hands": {}, "nan_samples": nan_samples}
    for hand in hands:
        flush(hand)
        glove = gloves[ep["layouts"][hand]]
        x = np.concatenate(series[hand]) if series[hand] else np.zeros((0, glove.layout.num_live), np.float32)
        out["hands"][hand] = hand_stats(x, frames[hand], glove, ep["layouts"][hand])
    return out


def hand_stats(x: np.ndarray, frames: list[int], glove: Glove, layout_id: str) -> dict:
    """Mergeable sums of one episode hand's (T, L) taxel series."""
    x = np.clip(x.astype(np.float64), 0.0, 1.0)
    zeros, hist = value_histogram(x.ravel())
    contact = x > CONTACT_THRESHOLD
    regions = {}
    names = np.asarray(glove.regions)
    for name in sorted(set(glove.regions)):
        cols = names == name
        hit = contact[:, cols]
        regions[name] = {"taxels": int(cols.sum()), "contact_frames": int(hit.any(axis=1).sum()),
                         "pressure_sum": float(x[:, cols][hit].sum()), "pressure_count": int(hit.sum())}
    frame_max = x.max(axis=1) if len(x) else np.zeros(0)
    return {
        "layout": layout_id, "frames": int(len(x)), "contact_frames": int(contact.any(axis=1).sum()),
        "zeros": zeros, "hist": hist.tolist(), "max": float(x.max()) if x.size else 0.0,
        "taxel_sum": x.sum(axis=0).tolist(), "taxel_sumsq": (x * x).sum(axis=0).tolist(),
        "regions": regions, "frame_index": list(frames), "frame_max": [round(float(v), 5) for v in frame_max],
        "health": classify(x, glove.taxels),
    }


def empty_hand(layout_id: str | None) -> dict:
    return {"layout": layout_id, "frames": 0, "contact_frames": 0, "zeros": 0, "hist": [0] * HIST_BINS,
            "max": 0.0, "taxel_sum": None, "taxel_sumsq": None, "regions": {}, "episodes": 0}


def merge_hand(into: dict, h: dict) -> dict:
    """Add one episode hand's sums into `into` (per-taxel sums only while every part has the same layout)."""
    into["episodes"] = into.get("episodes", 0) + 1
    into["frames"] += h["frames"]
    into["contact_frames"] += h["contact_frames"]
    into["zeros"] += h["zeros"]
    into["hist"] = (np.asarray(into["hist"], np.int64) + np.asarray(h["hist"], np.int64)).tolist()
    into["max"] = max(into["max"], h["max"])
    if into["episodes"] == 1:
        into["layout"] = h["layout"]
        into["taxel_sum"], into["taxel_sumsq"] = list(h["taxel_sum"]), list(h["taxel_sumsq"])
    elif into["layout"] != h["layout"]:
        into["layout"], into["taxel_sum"], into["taxel_sumsq"] = "(several)", None, None
    elif into["taxel_sum"] is not None:
        into["taxel_sum"] = (np.add(into["taxel_sum"], h["taxel_sum"])).tolist()
        into["taxel_sumsq"] = (np.add(into["taxel_sumsq"], h["taxel_sumsq"])).tolist()
    for name, r in h["regions"].items():
        acc = into["regions"].setdefault(name, {"taxels": r["taxels"], "contact_frames": 0,
                                                "pressure_sum": 0.0, "pressure_count": 0})
        for k in ("contact_frames", "pressure_sum", "pressure_count"):
            acc[k] += r[k]
    return into
