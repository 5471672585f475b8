"""Time: per-episode timestamps from the sample JSONs.

RGB timestamps strictly increase per episode; tactile timestamps never
decrease (a repeated tactile timestamp means one glove frame was paired with
two RGB frames, which nearest-neighbour sync allows when the glove is slower
than the camera: counted as a warning); gaps (> GAP_FACTOR periods) and fps
deviation (> FPS_TOLERANCE) warn; |t_rgb - t_tactile| above the sync
tolerance (episode sync report `max_skew_ns`, else the source pipeline's
`sync.max_skew_ms`, else DEFAULT_MAX_SKEW_MS) fails.

Shard workers fill a timestamp table (`empty_timestamps`, `record_timestamps`)
for their rows; the parent joins them by global row (`merge_timestamps`).
"""

from __future__ import annotations

import numpy as np

from htdata.format.shardio import sample_key
from htdata.format.table import HANDS
from htdata.validate.loaded import Loaded
from htdata.validate.report import Check
from htdata.validate.structure import group_rows

FPS_TOLERANCE = 0.05
GAP_FACTOR = 1.5
DEFAULT_MAX_SKEW_MS = 20.0


def empty_timestamps(n: int) -> dict[str, np.ndarray]:
    """Columns for n rows: ok (sample JSON readable), t_rgb, and t_<hand> / has_<hand> per hand."""
    ts = {"ok": np.zeros(n, bool), "t_rgb": np.zeros(n, np.int64)}
    for hand in HANDS:
        ts[f"t_{hand}"] = np.zeros(n, np.int64)
        ts[f"has_{hand}"] = np.zeros(n, bool)
    return ts


def record_timestamps(ts: dict[str, np.ndarray], i: int, meta: dict) -> None:
    """Row i's times from its (schema-valid) sample JSON."""
    ts["ok"][i] = True
    ts["t_rgb"][i] = meta["t_rgb_ns"]
    for hand in HANDS:
        if hand in meta["t_tactile_ns"]:
            ts[f"t_{hand}"][i] = meta["t_tactile_ns"][hand]
            ts[f"has_{hand}"][i] = True


def merge_timestamps(into: dict[str, np.ndarray], part: dict[str, np.ndarray], rows: np.ndarray) -> None:
    """Copy a worker's columns (its rows are global rows `rows`) into the dataset-wide table."""
    for k in into:
        into[k][rows] = part[k]


def max_skew_ns(manifest: dict, ep: dict) -> tuple[int, str]:
    """Sync tolerance of an episode: its sync report, else its source pipeline, else the default."""
    sync = ep.get("sync") or {}
    if isinstance(sync.get("max_skew_ns"), (int, float)):
        return int(sync["max_skew_ns"]), "episode sync report"
    for src in manifest.get("sources", []):
        names = {src.get("name"), (src.get("adapter") or {}).get("name")}
        if ep["source"] in names and isinstance((src.get("sync") or {}).get("max_skew_ms"), (int, float)):
            return int(round(src["sync"]["max_skew_ms"] * 1e6)), f"pipeline {src.get('name')}"
    return int(DEFAULT_MAX_SKEW_MS * 1e6), "default"


def check_time(ds: Loaded, ts: dict[str, np.ndarray], check: Check) -> None:
    rows = ds.index
    ep_rows = group_rows(rows["episode"], len(ds.episodes))
    for pos, ep in enumerate(ds.episodes):
        eid = ep["episode_id"]
        sel = ep_rows[pos][ts["ok"][ep_rows[pos]]]
        if sel.size == 0:
            check.skipped.append(f"{eid}: no readable sample JSON")
            continue
        sel = sel[np.argsort(rows["frame"][sel], kind="stable")]
        frames = rows["frame"][sel].astype(np.int64)
        check.checked["episodes"] += 1
        t_rgb = ts["t_rgb"][sel]
        d = np.diff(t_rgb)
        for r in np.flatnonzero(d <= 0)[:check.max_listed]:
            fr = int(frames[r + 1])
            check.fail("rgb_not_increasing", f"episode {eid}: t_rgb_ns of frame {fr} is not after frame "
                       f"{int(frames[r])}", episode=eid, frame=fr,
                       key=sample_key(eid, fr), expected=f"> {int(t_rgb[r])}", found=int(t_rgb[r + 1]))
        for hand in ep["hands"]:
            has = ts[f"has_{hand}"][sel]
            _check_hand_times(ds.manifest, ep, hand, frames[has], t_rgb[has], ts[f"t_{hand}"][sel][has], check)
        if d.size and (d > 0).all():
            _check_rate(ep, d, frames, check)


def _check_hand_times(manifest: dict, ep: dict, hand: str, frames: np.ndarray, t_rgb: np.ndarray,
                      t: np.ndarray, check: Check) -> None:
    """One hand of one episode: tactile times never go back, repeats warn, skew within tolerance."""
    eid = ep["episode_id"]
    dt = np.diff(t)
    for r in np.flatnonzero(dt < 0)[:check.max_listed]:
        fr = int(frames[r + 1])
        check.fail("tactile_not_increasing", f"episode {eid}: {hand} tactile time of frame {fr} "
                   f"goes back", episode=eid, frame=fr, hand=hand, key=sample_key(eid, fr),
                   expected=f">= {int(t[r])}", found=int(t[r + 1]))
    repeats = int((dt == 0).sum())
    if repeats:
        check.warn("tactile_repeated", f"episode {eid}: {repeats} RGB frame(s) share a {hand} "
                   f"tactile frame with the previous one", episode=eid, hand=hand, count=repeats)
    tol, tol_from = max_skew_ns(manifest, ep)
    skew = t_rgb - t
    over = np.flatnonzero(np.abs(skew) > tol)
    check.checked["skews"] += int(skew.size)
    for r in over[:check.max_listed]:
        fr = int(frames[r])
        check.fail("sync_skew", f"episode {eid} frame {fr}: |t_rgb - t_{hand}| = {abs(int(skew[r]))} "
                   f"ns exceeds the tolerance ({tol} ns, {tol_from})", episode=eid, frame=fr,
                   hand=hand, key=sample_key(eid, fr), expected=f"<= {tol}", found=int(skew[r]))


def _check_rate(ep: dict, d: np.ndarray, frames: np.ndarray, check: Check) -> None:
    """Measured fps against the recorded one, and gaps, from increasing RGB time steps `d`."""
    eid = ep["episode_id"]
    period = float(np.median(d))
    measured = 1e9 / period
    dev = abs(measured - ep["fps"]) / ep["fps"]
    if dev > FPS_TOLERANCE:
        check.warn("fps_deviation", f"episode {eid}: measured {measured:.3f} fps vs recorded "
                   f"{ep['fps']}", episode=eid, expected=ep["fps"], found=round(measured, 3))
    gaps = np.flatnonzero(d > GAP_FACTOR * 1e9 / ep["fps"])
    if gaps.size:
        check.warn("gap", f"episode {eid}: {gaps.size} gap(s) over {GAP_FACTOR} frame periods, "
                   f"largest {int(d.max())} ns after frame {int(frames[int(np.argmax(d))])}",
                   episode=eid, count=int(gaps.size), found=int(d.max()))
