"""Per-episode tactile statistics: one pass over an episode's tactile members, mergeable results.

`compute_episode(reader, pos, gloves)` reads only the episode's tactile
members (never the JPEG), raw rows or stored maps (below), and returns, per hand, the mergeable
sums `merge_hand` adds up: frames, contact frames, per-taxel count / sum /
sum of squares, per-region contact frames and pressure sums, a fixed-bin
histogram of the values (plus exact zeros and the max), the per-frame max
(what `htdata trim --idle` needs) and the taxel health
(htdata/glove/health.py). A map holding NaN/Inf is left out and named in
"nan_samples" (episode, frame, hand, key).

Values are NORMALISED [0,1] taxel values. Where the dataset stores the raw
glove rows (format 3: members raw_<hand>.npy, calibration in the episode
record) they come from the raw row paired with each frame under the
episode's calibration (`htdata.glove.calibration.episode_normaliser`): exact, and
a small npy decode instead of a 224x224 EXR decode plus a sparse sampling
product. Such hands also get a raw-unit sketch (values clipped to [0, the
layout's max] in HIST_BINS bins, exact min and max) for raw quantiles.
Datasets without raw rows (format 1/2, `keep_raw = false`) are read from
their maps sampled at taxel centres (`Rasteriser(layout).sample`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from htdata.errors import DatasetError
from htdata.format.canvas import MAP_SHAPE
from htdata.format.table import HANDS, JSON_MEMBER, SIZE_FIELDS, raw_member, tactile_member
from htdata.format.tactilecodec import decode_exr_pixels
from htdata.glove.calibration import episode_normaliser
from htdata.glove.canonical import parse_canonical
from htdata.glove.contact import OLD_RULE, THRESHOLD, ContactRule, episode_rule
from htdata.glove.health import TaxelGrid, classify
from htdata.glove.layouts import CanonicalHand, Layout, parse_layout
from htdata.glove.rasterise import Rasteriser
from htdata.glove.rawhealth import classify_raw
from htdata.read.rawstream import paired_row, paired_source_row
from htdata.store import storage

CONTACT_THRESHOLD = THRESHOLD  # the old rule's level (htdata.glove.contact), kept beside the calibrated one
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
    canonical = parse_canonical(json.loads(storage.read_text(storage.join(reader.root, canon_file))),
                                f"{reader.root}/{canon_file}")
    gloves = {}
    for layout_id, entry in reader.manifest["layouts"].items():
        where = f"{reader.root}/{entry['file']}"
        try:
            layout = parse_layout(reader.layout(layout_id), where, canonical=canonical)
        except (ValueError, KeyError) as exc:
            raise DatasetError(f"{where}: layout {layout_id!r} is not a glove layout the stats can sample "
                               f"taxels from: {exc}") from exc
        gloves[layout_id] = Glove(layout, canonical)
    return gloves


def raw_hands(reader, pos: int) -> list[str]:
    """Hands of episode `pos` whose values come from the stored raw rows (format 3, calibration recorded).

    A hand qualifies when every sample holding its map also holds its raw
    rows and the episode record names its calibration; the others (datasets
    of format 1/2, `keep_raw = false`) are read from their maps.
    """
    ep = reader.episodes[pos]
    first, n = reader.episode_range(pos)
    rows = reader.index[first:first + n]
    out = []
    for hand in (h for h in HANDS if h in ep["layouts"]):
        raw_col, map_col = SIZE_FIELDS.get(raw_member(hand)), SIZE_FIELDS[tactile_member(hand)]
        if raw_col is None or raw_col not in rows.dtype.names or not (ep.get("calibration") or {}).get(hand):
            continue
        if n and np.all((rows[raw_col] > 0) | (rows[map_col] == 0)) and np.any(rows[raw_col] > 0):
            out.append(hand)
    return out


def all_finite(pixels: np.ndarray) -> bool:
    """No NaN/Inf in a decoded map; float16 by its bits (exponent all ones), 4x faster than np.isfinite."""
    if pixels.dtype == np.float16:
        return bool((pixels.view(np.uint16) & 0x7FFF).max(initial=0) < 0x7C00)
    return bool(np.isfinite(pixels).all())


class _Series:
    """One episode hand's values as read: raw paired rows or maps, with their frame numbers."""

    def __init__(self):
        self.items: list[np.ndarray] = []
        self.frames: list[int] = []
        self.keys: list[tuple[str, int]] = []     # (sample key, global sample index): errors name the sample
        self.source_rows: list[int] = []          # paired source row numbers (baseline = "drift" only)


def _read_episode(reader, pos: int, from_raw: list[str], nan_samples: list, drifting: tuple = ()
                  ) -> dict[str, _Series]:
    """Stream the episode's members once: raw rows for `from_raw` hands, maps for the other hands
    (+ the paired source row numbers of the `drifting` hands)."""
    ep = reader.episodes[pos]
    first, n = reader.episode_range(pos)
    hands = [h for h in HANDS if h in ep["layouts"]]
    wanted = {h: raw_member(h) if h in from_raw else tactile_member(h) for h in hands}
    suffixes = tuple(wanted.values()) + ((JSON_MEMBER,) if from_raw else ())
    series = {h: _Series() for h in hands}
    for i in range(first, first + n):
        _, key, members = reader.read_sample(i, suffixes)
        for hand in hands:
            data = members.get(wanted[hand])
            if data is None:
                continue
            where = f"{reader.root}: {key}"
            if hand in from_raw:
                value = paired_row(members, hand, where)
                if hand in drifting:
                    series[hand].source_rows.append(paired_source_row(members, hand, where))
            else:
                value = decode_exr_pixels(data, f"{where}.{wanted[hand]}")  # half as stored: converted once
                if value.shape != MAP_SHAPE:
                    raise DatasetError(f"{where}.{wanted[hand]}: decoded tactile map has shape {value.shape}, "
                                       f"expected {MAP_SHAPE}")
                if not all_finite(value):
                    nan_samples.append({"episode": ep["episode_id"], "frame": i - first, "hand": hand, "key": key,
                                        "sample": i, "nonfinite_pixels": int((~np.isfinite(value)).sum())})
                    continue
            series[hand].items.append(value)
            series[hand].frames.append(i - first)
            series[hand].keys.append((key, i))
    return series


def _map_taxels(s: _Series, glove: "Glove") -> np.ndarray:
    """(T, L) live taxel values of stored maps, sampled CHUNK maps at a time."""
    live = glove.layout.live_mask
    parts = [glove.rasteriser.sample(np.stack(s.items[k:k + CHUNK]))[:, live] for k in range(0, len(s.items), CHUNK)]
    return np.concatenate(parts) if parts else np.zeros((0, glove.layout.num_live), np.float32)


def _raw_taxels(s: _Series, normaliser, glove: "Glove", ep: dict, hand: str, nan_samples: list):
    """((T, L) normalised live values, (T, H, W) raw rows) of the paired raw rows, exactly as calibrated."""
    live = glove.layout.live_mask
    if not s.items:
        return np.zeros((0, glove.layout.num_live), np.float32), np.zeros((0, *glove.layout.grid), np.float32)
    raw = np.stack(s.items)
    values, finite = normaliser.apply(raw, rows=s.source_rows if normaliser.cfg.knotted else None)
    if not finite.all():           # the ingest drops such frames: a stored one is damage, named like a NaN map
        for t in np.flatnonzero(~finite):
            nan_samples.append({"episode": ep["episode_id"], "frame": s.frames[t], "hand": hand, "key": s.keys[t][0],
                                "sample": s.keys[t][1], "nonfinite_taxels": int((~np.isfinite(raw[t][live])).sum())})
        s.frames = [f for f, ok in zip(s.frames, finite) if ok]
        values, raw = values[finite], raw[finite]
    return values[:, live], raw


def compute_episode(reader, pos: int, gloves: dict[str, Glove]) -> dict:
    """Stats of episode `pos` of `reader` (see the module docstring); JSON-ready."""

    ep = reader.episodes[pos]
    _, n = reader.episode_range(pos)
    from_raw = raw_hands(reader, pos)
    nan_samples: list = []
    normalisers = {hand: episode_normaliser(reader.manifest, ep, hand, gloves[ep["layouts"][hand]].layout)
                   for hand in from_raw}
    drifting = tuple(h for h, n in normalisers.items() if n.cfg.knotted)
    series = _read_episode(reader, pos, from_raw, nan_samples, drifting)
    out = {"episode_id": ep["episode_id"], "frames": n, "hands": {}, "nan_samples": nan_samples}
    for hand, s in series.items():
        glove = gloves[ep["layouts"][hand]]
        if hand in from_raw:
            x, raw = _raw_taxels(s, normalisers[hand], glove, ep, hand, nan_samples)
        else:
            x, raw = _map_taxels(s, glove), None
        rule = episode_rule(reader.manifest, ep, hand, glove.layout)
        floor = _taxel_floor(reader, ep, hand, glove, normalisers.get(hand)) if rule.press else None
        out["hands"][hand] = hand_stats(x, s.frames, glove, ep["layouts"][hand], raw, rule, floor)
    return out


def _taxel_floor(reader, ep: dict, hand: str, glove: "Glove", normaliser=None) -> np.ndarray | None:
    """(L,) noise floor of the episode hand's live taxels in value units (floor x scale), from its calibration
    record; None where none is recorded (the contact rule then goes by the floor alone)."""
    if normaliser is None:
        try:
            normaliser = episode_normaliser(reader.manifest, ep, hand, glove.layout)
        except DatasetError:
            return None
    if not normaliser.cfg.fits:
        return None
    return normaliser.floor[glove.layout.live_mask] * np.float32(normaliser.cfg.scale)


def raw_histogram(raw: np.ndarray, top: float) -> dict:
    """Mergeable raw-unit sketch: values clipped to [0, top] as (zeros, HIST_BINS bins of top), exact min/max."""
    v = np.asarray(raw, np.float64).ravel()
    v = v[np.isfinite(v)]
    zeros, hist = value_histogram(np.clip(v / top, 0.0, 1.0))
    return {"raw_top": float(top), "raw_zeros": zeros, "raw_hist": hist.tolist(), "raw_count": int(v.size),
            "raw_min": float(v.min()) if v.size else None, "raw_max": float(v.max()) if v.size else None}


def hand_stats(x: np.ndarray, frames: list[int], glove: Glove, layout_id: str, raw: np.ndarray | None = None,
               rule: ContactRule = OLD_RULE, floor: np.ndarray | None = None) -> dict:
    """Mergeable sums of one episode hand's (T, L) taxel series (+ raw-unit sketch and raw-row taxel health
    when `raw`, its (T, H, W) raw rows, is given).

    Contact follows `rule` (htdata.glove.contact: the episode hand's calibration, with `floor`, its (L,)
    per-taxel noise floor in value units where recorded); "contact_frames_threshold" keeps the old count
    (any taxel > 0.02) beside it.
    """
    x = np.clip(x.astype(np.float64), 0.0, 1.0)
    zeros, hist = value_histogram(x.ravel())
    in_contact = rule.frames(x, floor) if len(x) else np.zeros(0, bool)
    contact = rule.taxels(x, floor) & in_contact[:, None]     # a region touches only in a frame the hand touches
    regions = {}
    names = np.asarray(glove.regions)
    for name in sorted(set(glove.regions)):
        cols = names == name
        hit = contact[:, cols]
        regions[name] = {"taxels": int(cols.sum()), "contact_frames": int(hit.any(axis=1).sum()),
                         "pressure_sum": float(x[:, cols][hit].sum()), "pressure_count": int(hit.sum())}
    frame_max = x.max(axis=1) if len(x) else np.zeros(0)
    out = {
        "layout": layout_id, "frames": int(len(x)), "contact_frames": int(in_contact.sum()),
        "contact_frames_threshold": int((x > CONTACT_THRESHOLD).any(axis=1).sum()) if len(x) else 0,
        "contact_rule": rule.to_dict(), "frame_contact": in_contact.astype(int).tolist(),
        "values_from": "raw" if raw is not None else "maps",
        "zeros": zeros, "hist": hist.tolist(), "max": float(x.max()) if x.size else 0.0,
        "taxel_sum": x.sum(axis=0).tolist(), "taxel_sumsq": (x * x).sum(axis=0).tolist(),
        "regions": regions, "frame_index": list(frames), "frame_max": [round(float(v), 5) for v in frame_max],
        # from the raw rows where stored: the glove's own health, whatever the calibration
        "health": classify(x, glove.taxels) if raw is None else classify_raw(raw, glove.layout, glove.taxels),
    }
    if raw is not None:
        out.update(raw_histogram(raw[:, glove.layout.live_mask], float(glove.layout.value["max"])))
    return out


def empty_hand(layout_id: str | None) -> dict:
    return {"layout": layout_id, "frames": 0, "contact_frames": 0, "contact_frames_threshold": 0, "contact_rules": [], "zeros": 0, "hist": [0] * HIST_BINS,
            "max": 0.0, "taxel_sum": None, "taxel_sumsq": None, "regions": {}, "episodes": 0,
            "frames_from_raw": 0, "raw_top": None}


def _merge_raw(into: dict, h: dict) -> None:
    """Raw-unit sketches add up while their range (the layout's max) is one; else they are dropped ("several")."""
    if "raw_hist" not in h:
        return
    into["frames_from_raw"] += h["frames"]
    if into["raw_top"] is None:
        into.update({k: h[k] for k in ("raw_top", "raw_zeros", "raw_count", "raw_min", "raw_max")})
        into["raw_hist"] = list(h["raw_hist"])
    elif into["raw_top"] == "(several)" or into["raw_top"] != h["raw_top"]:
        into["raw_top"], into["raw_hist"] = "(several)", None
    else:
        into["raw_hist"] = (np.asarray(into["raw_hist"], np.int64) + np.asarray(h["raw_hist"], np.int64)).tolist()
        into["raw_zeros"] += h["raw_zeros"]
        into["raw_count"] += h["raw_count"]
        mins = [v for v in (into["raw_min"], h["raw_min"]) if v is not None]
        maxs = [v for v in (into["raw_max"], h["raw_max"]) if v is not None]
        into["raw_min"], into["raw_max"] = (min(mins) if mins else None), (max(maxs) if maxs else None)


def merge_hand(into: dict, h: dict) -> dict:
    """Add one episode hand's sums into `into` (per-taxel sums only while every part has the same layout)."""
    into["episodes"] = into.get("episodes", 0) + 1
    into["frames"] += h["frames"]
    into["contact_frames"] += h["contact_frames"]
    into["contact_frames_threshold"] = into.get("contact_frames_threshold", 0) + h.get("contact_frames_threshold", 0)
    rule = h.get("contact_rule")
    if rule is not None and rule not in into.setdefault("contact_rules", []):
        into["contact_rules"].append(rule)
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
    _merge_raw(into, h)
    for name, r in h["regions"].items():
        acc = into["regions"].setdefault(name, {"taxels": r["taxels"], "contact_frames": 0,
                                                "pressure_sum": 0.0, "pressure_count": 0})
        for k in ("contact_frames", "pressure_sum", "pressure_count"):
            acc[k] += r[k]
    return into
