"""Pair RGB frames with tactile frames by timestamp.

Clocks are compared as recorded (int64 ns). Each RGB frame is paired with the
nearest tactile frame of every present hand (vectorised `np.searchsorted`).
A frame whose skew exceeds `max_skew_ns` for any hand is dropped and listed
with a reason: nothing is ever paired silently across a large gap.

Clock lag (htdata/source/lag.py, pipeline `[sync] lag`): `pair(..., lag=decision)`
subtracts `decision.shift_ns` from every tactile timestamp before pairing
(the paired t_tactile_ns are then on the RGB clock) and records
`decision.to_dict()` as the report's "lag" entry, applied or not (a declined
one also as a warning). Without a decision the clocks are paired as recorded
and the report has no "lag" key.

Timestamp cleaning (`clean_timestamps`), applied to every stream first:
- non-monotonic timestamps are put in time order by a STABLE sort (equal
  timestamps keep their file order) and a warning is recorded;
- exact duplicates keep the FIRST occurrence in file order; the others are
  removed (for RGB they are dropped frames with reason "duplicate_timestamp");
- two consecutive timestamps more than a day apart (`MAX_GAP_NS`, e.g. a last
  stamp of int64 max) are refused, naming the stream: no recording has such a gap.
The warnings go to the episode record and, through the ingest report's
`episode_warnings`, to stderr.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from htdata.errors import ArgumentError

log = logging.getLogger(__name__)

SYNC_POLICIES = ("nearest",)
MAX_GAP_NS = 24 * 3_600_000_000_000   # one day between two frames of one stream: no recording, a broken clock


@dataclass
class CleanReport:
    """What `clean_timestamps` did to one stream."""

    name: str
    n_in: int
    n_out: int
    reordered: int          # positions whose file order differs from time order
    duplicates: int         # exact duplicates removed
    duplicate_indices: np.ndarray  # original indices removed as duplicates
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"name": self.name, "n_in": self.n_in, "n_out": self.n_out,
                "reordered": self.reordered, "duplicates": self.duplicates,
                "warnings": list(self.warnings)}


@dataclass
class SyncResult:
    rgb_index: np.ndarray                 # (K,) int64 original RGB frame indices, in time order
    tactile_index: dict[str, np.ndarray]  # hand -> (K,) int64 original tactile indices
    skew_ns: dict[str, np.ndarray]        # hand -> (K,) int64 signed rgb - tactile
    t_rgb_ns: np.ndarray                  # (K,) int64
    t_tactile_ns: dict[str, np.ndarray]   # hand -> (K,) int64
    dropped: list[tuple[int, str]]        # (original rgb index, reason)
    report: dict


def _as_timestamps(ts, name: str) -> np.ndarray:
    arr = np.asarray(ts)
    if arr.ndim != 1:
        raise ValueError(f"{name}: timestamps must be 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name}: empty timestamp stream (no frames)")
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name}: timestamps must be integer ns, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def clean_timestamps(ts, name: str) -> tuple[np.ndarray, CleanReport]:
    """Return (order, report): `order` are original indices, time-sorted, duplicates removed.

    `ts[order]` is strictly increasing. Raises ValueError for an empty or
    non-integer stream, naming it.
    """
    arr = _as_timestamps(ts, name)
    if strictly_increasing(arr):   # the usual stream, and a long one: nothing to clean, no per-row sort or copy
        _refuse_impossible_gap(arr, name)
        return np.arange(arr.size), CleanReport(name=name, n_in=int(arr.size), n_out=int(arr.size), reordered=0,
                                                duplicates=0, duplicate_indices=np.zeros(0, np.int64))
    order = np.argsort(arr, kind="stable")
    reordered = int(np.count_nonzero(order != np.arange(arr.size)))
    sorted_ts = arr[order]
    is_dup = np.zeros(arr.size, dtype=bool)
    is_dup[1:] = sorted_ts[1:] == sorted_ts[:-1]
    dup_idx = np.sort(order[is_dup])
    keep = order[~is_dup]
    _refuse_impossible_gap(arr[keep], name)
    warnings: list[str] = []
    if keep.size == 1 and arr.size > 1:
        warnings.append(f"{name}: all {arr.size} timestamps are equal (a stuck clock?); kept the first frame only")
    if reordered:
        warnings.append(f"{name}: timestamps not monotonic; stable-sorted ({reordered} frames moved)")
    if dup_idx.size:
        warnings.append(f"{name}: {dup_idx.size} exact duplicate timestamps; kept the first of each")
    for w in warnings:
        log.warning(w)
    report = CleanReport(name=name, n_in=int(arr.size), n_out=int(keep.size), reordered=reordered,
                         duplicates=int(dup_idx.size), duplicate_indices=dup_idx, warnings=warnings)
    return keep, report


# rows compared per step by the checks over a whole stream: their temporaries stay ~2 MB however long it is
_BLOCK = 1 << 18


def _pairs(n: int):
    """(start, stop) blocks of the n - 1 consecutive pairs (i, i + 1) of n values."""
    return ((i, min(i + _BLOCK, n - 1)) for i in range(0, max(n - 1, 0), _BLOCK))


def strictly_increasing(arr: np.ndarray) -> bool:
    """True when every timestamp is later than the one before it (no reorder, no duplicate), checked a block
    at a time (no per-row temporary over a long stream)."""
    return all(bool(np.all(arr[a + 1:b + 1] > arr[a:b])) for a, b in _pairs(arr.size))


def _refuse_impossible_gap(sorted_ts: np.ndarray, name: str) -> None:
    """A gap between two consecutive timestamps longer than MAX_GAP_NS is a broken clock, not a recording."""
    if sorted_ts.size < 2:
        return
    worst, gap = 0, -1
    for a, b in _pairs(sorted_ts.size):
        # differences of sorted int64 taken as uint64: exact even when they overflow int64 (a last stamp of int64 max)
        gaps = sorted_ts[a + 1:b + 1].view(np.uint64) - sorted_ts[a:b].view(np.uint64)
        at = int(np.argmax(gaps))
        if int(gaps[at]) > gap:
            worst, gap = a + at, int(gaps[at])
    if gap > MAX_GAP_NS:
        raise ValueError(f"{name}: timestamps {int(sorted_ts[worst])} and {int(sorted_ts[worst + 1])} ns lie "
                         f"{gap / 86400e9:.3g} days apart (more than {MAX_GAP_NS // 3_600_000_000_000} "
                         f"h): a broken clock, no recording has such a gap")


def nearest(sorted_ts: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Position in strictly increasing `sorted_ts` nearest to each query (ties -> earlier)."""
    right = np.searchsorted(sorted_ts, query, side="left")
    right = np.clip(right, 0, sorted_ts.size - 1)
    left = np.clip(right - 1, 0, sorted_ts.size - 1)
    take_left = np.abs(query - sorted_ts[left]) <= np.abs(sorted_ts[right] - query)
    return np.where(take_left, left, right)


def _skew_stats(skew: np.ndarray, t_rgb: np.ndarray) -> dict:
    if skew.size == 0:
        return {"offset_ns": None, "drift_ns_per_s": None, "max_abs_skew_ns": None,
                "median_abs_skew_ns": None}
    abs_skew = np.abs(skew)
    drift = 0.0
    if skew.size >= 2 and t_rgb[-1] > t_rgb[0]:
        # Least-squares slope of skew against time (seconds); centred for float precision.
        t = (t_rgb - t_rgb[0]).astype(np.float64) / 1e9
        s = skew.astype(np.float64)
        tc = t - t.mean()
        drift = float(np.dot(tc, s - s.mean()) / np.dot(tc, tc))
    return {"offset_ns": int(np.median(skew)), "drift_ns_per_s": drift,
            "max_abs_skew_ns": int(abs_skew.max()), "median_abs_skew_ns": int(np.median(abs_skew))}


def pair(rgb_ts, tactile_ts: dict[str, np.ndarray], max_skew_ns: int,
         policy: str = "nearest", lag=None) -> SyncResult:
    """Pair each RGB frame with the nearest tactile frame of every hand.

    `lag`: an `htdata.source.lag.LagDecision` (or None): its `shift_ns` (0 when not
    applied) comes off every tactile timestamp first; its `to_dict()` is the
    report's "lag" entry.

    Drop reasons: "duplicate_timestamp" (RGB duplicate), "tactile_out_of_range:<hand>"
    (the RGB frame lies outside that hand's recorded span by more than the
    tolerance, e.g. the glove started later), "sync_skew:<hand>" (gap inside
    the stream). A frame failing several hands gets the first hand in sorted order.
    """
    if policy not in SYNC_POLICIES:
        raise ArgumentError(f"unknown sync policy {policy!r}; expected one of {SYNC_POLICIES}")
    if max_skew_ns < 0:
        raise ArgumentError(f"max_skew_ns must be >= 0, got {max_skew_ns}")
    if not tactile_ts:
        raise ValueError("no tactile stream to pair with")
    shift = np.int64(lag.shift_ns if lag is not None and lag.applied else 0)
    rgb_raw = _as_timestamps(rgb_ts, "rgb")
    rgb_order, rgb_rep = clean_timestamps(rgb_raw, "rgb")
    t_rgb = rgb_raw[rgb_order]
    keep = np.ones(rgb_order.size, dtype=bool)
    reason = np.full(rgb_order.size, "", dtype=object)

    hands = sorted(tactile_ts)
    per_hand = {}
    for hand in hands:
        raw = _as_timestamps(tactile_ts[hand], f"tactile_{hand}")
        raw = raw - shift if shift else raw     # no per-row copy of a long stream when nothing shifts it
        order, rep = clean_timestamps(raw, f"tactile_{hand}")
        t_tac = raw if rep.n_out == rep.n_in and not rep.reordered else raw[order]
        pos = nearest(t_tac, t_rgb)
        skew = t_rgb - t_tac[pos]
        bad = np.abs(skew) > max_skew_ns
        outside = (t_rgb < t_tac[0] - max_skew_ns) | (t_rgb > t_tac[-1] + max_skew_ns)
        new_bad = bad & keep
        reason[new_bad & outside] = f"tactile_out_of_range:{hand}"
        reason[new_bad & ~outside] = f"sync_skew:{hand}"
        keep &= ~bad
        per_hand[hand] = (order[pos], skew, t_tac[pos], rep)

    dropped = [(int(i), "duplicate_timestamp") for i in rgb_rep.duplicate_indices]
    dropped += [(int(i), str(r)) for i, r in zip(rgb_order[~keep], reason[~keep])]
    dropped.sort()
    t_kept = t_rgb[keep]
    reasons: dict[str, int] = {}
    for _, r in dropped:
        reasons[r] = reasons.get(r, 0) + 1

    hand_reports = {}
    for hand, (tidx, skew, ttac, rep) in per_hand.items():
        hand_reports[hand] = {**_skew_stats(skew[keep], t_kept),
                              "duplicates": rep.duplicates, "reordered": rep.reordered,
                              "n_tactile": rep.n_in}
    report = {
        "policy": policy, "max_skew_ns": int(max_skew_ns),
        "n_rgb": rgb_rep.n_in, "kept": int(keep.sum()), "drops": len(dropped),
        "drop_reasons": reasons,
        "rgb_duplicates": rgb_rep.duplicates, "rgb_reordered": rgb_rep.reordered,
        "hands": hand_reports,
        "warnings": rgb_rep.warnings + [w for h in per_hand.values() for w in h[3].warnings],
    }
    if lag is not None:
        report["lag"] = lag.to_dict()
        if not lag.applied:   # asked for and declined: a note in the episode record too
            report["warnings"].append(f"tactile-video lag {lag.reason}")
    return SyncResult(
        rgb_index=rgb_order[keep],
        tactile_index={h: v[0][keep] for h, v in per_hand.items()},
        skew_ns={h: v[1][keep] for h, v in per_hand.items()},
        t_rgb_ns=t_kept,
        t_tactile_ns={h: v[2][keep] for h, v in per_hand.items()},
        dropped=dropped,
        report=report,
    )
