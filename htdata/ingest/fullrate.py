"""Keep every recorded frame: which sample stores which raw glove row, and RGB frames without tactile.

A glove often runs faster than the camera (a 100 Hz glove beside 30 Hz
video): pairing keeps one row per RGB frame. So nothing is lost, each sample
stores in its `raw_<hand>.npy` member the row paired with its frame plus
every UNPAIRED row whose time falls at or after the frame's RGB time and
before the next sample's (rows before the first sample go to the first,
rows after the last to the last), but only within a bounded span of the
sample's frame time (`raw_span_ns`: 1 s, or 2 frame intervals for a camera
slower than 2 fps): a glove that ran on for minutes after (or before) the
video, or through a long video gap, would otherwise put every one of those
rows into one sample (1e6 rows: a 1 GB sample, 3.5 GB of RAM). Rows outside
the span are dropped and counted: the episode record's "raw_rows_dropped"
and a note in the ingest report and on stderr. The count is bounded too
(`raw_row_cap`: two spans at the glove's nominal rate, never faster than
MAX_GLOVE_RATE_HZ): rows over it, the farthest from the frame time, are
dropped and counted as "raw_rows_capped" (record, report, stderr). Rows of frames the ingest drops
(non-finite or out-of-range values) are unpaired rows too and land in the
previous kept sample (the next one when none precedes). Duplicate-timestamp
rows, which sync cannot pair, are stored the same way. Within a sample the
rows are in time order (then source order); meta names their timestamps
("raw_t_ns"), source row numbers ("raw_row") and the paired row's position
("raw_paired"), so the full-rate stream is the union over the episode's
samples, deduplicated by source row (a row paired with two frames is stored
twice). Rows keep the source dtype, bit for bit.

RGB frames the pairing could not use (no tactile row within the skew, or
tactile values the ingest dropped) are kept as RGB-only samples when
`[rgb] keep_unpaired` (default): no tactile member, meta "hands" all false
and "rgb_only" naming the reason; they hold no raw rows. A frame whose
timestamp duplicates an earlier frame's has no time of its own: it stays
dropped (counted as "duplicate_timestamp"). `FrameQueue` puts both kinds
out in time order while holding the last paired frame open for the rows of
frames dropped after it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from htdata.source.sync import strictly_increasing

# Bounded by count too: a sample stores at most `raw_row_cap` unpaired rows per hand, the rows two spans hold
# at the glove's nominal rate (median interval between its distinct timestamps), never more than a glove at
# MAX_GLOVE_RATE_HZ makes (rows packed 100 ns apart, or a stuck clock giving 300k rows one timestamp,
# would otherwise reach GBs). The rows nearest the frame time are kept; the rest are counted as capped.
MAX_GLOVE_RATE_HZ = 2000
ROW_CAP_SLACK = 16
MIN_RAW_SPAN_NS = 1_000_000_000   # a sample stores unpaired rows at most this far from its frame time ...
RAW_SPAN_INTERVALS = 2             # ... or this many frame intervals, when that is longer (slow cameras)


# rows of a glove stream planned per step: what the plan holds beyond the stream's own timestamps is the rows it
# keeps plus one block's temporaries (~15 MB), not ~95 bytes for every row of the stream (issue 35)
_BLOCK = 1 << 18


def raw_span_ns(t_frames: np.ndarray) -> int:
    """How far from its frame time a sample stores unpaired rows (see the module docstring)."""
    d = np.diff(np.unique(np.asarray(t_frames, dtype=np.int64)))
    return max(MIN_RAW_SPAN_NS, RAW_SPAN_INTERVALS * int(np.median(d)) if d.size else 0)


def raw_row_cap(timestamps: np.ndarray, span_ns: int) -> int:
    """Most unpaired rows of one hand a sample stores (see MAX_GLOVE_RATE_HZ)."""
    floor = 1_000_000_000 // MAX_GLOVE_RATE_HZ
    median = _median_interval(np.asarray(timestamps, dtype=np.int64))
    interval = max(median if median is not None else floor, floor)
    return 2 * int(span_ns) // interval + ROW_CAP_SLACK


def _median_interval(ts: np.ndarray) -> int | None:
    """int(np.median(np.diff(np.unique(ts)))), or None for fewer than two distinct stamps; an increasing
    stream (the usual one) takes one int64 per row for it (np.unique and np.median would copy it twice more)."""
    d = np.diff(ts) if strictly_increasing(ts) else np.diff(np.unique(ts))
    if not d.size:
        return None
    k = d.size // 2
    middle = [k - 1, k] if d.size % 2 == 0 else [k]
    d.partition(middle)                     # in place: np.median's own value, without its copy
    return int(np.mean(d[middle]))


def _cap_per_slot(slot: np.ndarray, distance: np.ndarray, rows: np.ndarray, cap: int) -> np.ndarray:
    """Mask of the rows kept: per slot, the `cap` nearest its frame time (then source order)."""
    order = np.lexsort((rows, distance, slot))
    sorted_slots = slot[order]
    rank = np.arange(order.size) - np.searchsorted(sorted_slots, sorted_slots, side="left")
    keep = np.zeros(slot.size, dtype=bool)
    keep[order[rank < cap]] = True
    return keep


@dataclass
class RowPlan:
    """One hand's unpaired rows, grouped by the synchronised frame (slot) that stores them."""
    timestamps: np.ndarray   # (M,) int64 all rows as recorded
    rows: np.ndarray         # unpaired source rows, sorted by (slot, time, row)
    slots: np.ndarray        # their slot (position in the synchronised frames), same order
    dropped: int = 0         # unpaired rows farther than raw_span_ns from every sample: stored nowhere
    span_ns: int = MIN_RAW_SPAN_NS
    capped: int = 0          # unpaired rows over a sample's raw_row_cap: stored nowhere
    cap: int = 0

    @classmethod
    def build(cls, timestamps, paired_rows: np.ndarray, t_frames: np.ndarray) -> "RowPlan":
        """The plan of one hand's stream: its unpaired rows near a frame, `cap` at most per slot (the module
        docstring). Read a block of rows at a time, each block's rows already capped per slot (the `cap`
        nearest of all rows are among the `cap` nearest of each block), so memory follows the rows kept."""
        ts = np.asarray(timestamps, dtype=np.int64)
        t_frames = np.asarray(t_frames, dtype=np.int64)
        paired = np.zeros(ts.size, dtype=bool)
        paired[np.asarray(paired_rows, dtype=np.int64)] = True
        span = raw_span_ns(t_frames)
        cap = raw_row_cap(ts, span)
        blocks, dropped, near_total = [], 0, 0
        for start in range(0, ts.size, _BLOCK):
            rows = start + np.flatnonzero(~paired[start:start + _BLOCK])
            rows, t, slot, far = _near_rows(rows, ts[rows], t_frames, span)
            dropped += far
            near_total += rows.size
            if rows.size > cap:     # the block's own cap: what no later block can bring back
                keep = _cap_per_slot(slot, np.abs(t - t_frames[slot]) if t_frames.size else t, rows, cap)
                rows, t, slot = rows[keep], t[keep], slot[keep]
            blocks.append((rows, t, slot))
        unpaired, t, slot = (np.concatenate(parts) for parts in zip(*blocks)) if blocks else \
            (np.zeros(0, np.int64),) * 3
        if unpaired.size > cap:
            keep = _cap_per_slot(slot, np.abs(t - t_frames[slot]) if t_frames.size else t, unpaired, cap)
            unpaired, t, slot = unpaired[keep], t[keep], slot[keep]
        order = np.lexsort((unpaired, t, slot))
        return cls(timestamps=ts, rows=unpaired[order], slots=slot[order], dropped=dropped, span_ns=span,
                   capped=int(near_total - unpaired.size), cap=cap)

    def rows_for(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """(rows, slots) of the unpaired rows stored by slots [start, stop)."""
        a, b = np.searchsorted(self.slots, [start, stop], side="left")
        return self.rows[a:b], self.slots[a:b]


def _near_rows(rows: np.ndarray, t: np.ndarray, t_frames: np.ndarray, span: int):
    """(rows, t, slot, count dropped): the rows within `span` of their frame (a row in a video gap goes to the
    end it is near), each with its slot; rows farther from every frame are only counted (no frame: all kept)."""
    slot = np.clip(np.searchsorted(t_frames, t, side="right") - 1, 0, max(t_frames.size - 1, 0))
    if not t_frames.size:
        return rows, t, slot, 0
    near = np.abs(t - t_frames[slot]) < span
    nxt = np.minimum(slot + 1, t_frames.size - 1)     # in a video gap: the end near the next frame
    to_next = ~near & (nxt > slot) & (t_frames[nxt] - t < span)
    slot = np.where(to_next, nxt, slot)
    near |= to_next
    return rows[near], t[near], slot[near], int(rows.size - np.count_nonzero(near))


@dataclass
class RawRows:
    """Raw rows gathered for one sample and hand: source row numbers, timestamps, values."""
    rows: list[int] = field(default_factory=list)
    times: list[int] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    paired_row: int | None = None

    def add(self, row: int, t: int, value: np.ndarray) -> None:
        self.rows.append(int(row))
        self.times.append(int(t))
        self.values.append(value)

    def extend(self, other: "RawRows") -> None:
        self.rows += other.rows
        self.times += other.times
        self.values += other.values

    def finish(self, grid: tuple[int, int], dtype) -> tuple[np.ndarray, dict]:
        """(array (R,H,W) in time order, meta {"t_ns", "row", "paired"}); paired = position of the paired row."""
        order = sorted(range(len(self.rows)), key=lambda i: (self.times[i], self.rows[i]))
        arr = (np.stack([self.values[i] for i in order]) if order
               else np.zeros((0, *grid), dtype=dtype))
        rows = [self.rows[i] for i in order]
        meta = {"t_ns": [self.times[i] for i in order], "row": rows}
        if self.paired_row is not None:
            meta["paired"] = rows.index(self.paired_row)
        return np.ascontiguousarray(arr), meta


class FrameQueue:
    """Frames out in time order; the last paired frame stays open for the rows of frames dropped after it.

    Frames are pushed in time order (`push`); `unpaired_rows` hands over the
    raw rows of a synchronised frame that was dropped. `push` and `close`
    return the frames ready to be written, each paired one finished
    (`finish(frame)`: its rows turned into arrays) when nothing can join it.
    """

    def __init__(self, finish):
        self.finish = finish
        self.held: list = []            # [last paired frame, rgb-only frames after it ...]
        self.lead: dict[str, RawRows] = {}   # rows before any paired frame: go to the first

    def unpaired_rows(self, rows: dict[str, RawRows]) -> None:
        target = self.held[0].raw if self.held else self.lead
        for hand, rr in rows.items():
            rr.paired_row = None
            target.setdefault(hand, RawRows()).extend(rr)

    def push(self, frame, paired: bool) -> list:
        if not paired:
            if self.held:
                self.held.append(frame)
                return []
            return [frame]
        for hand, rr in self.lead.items():
            frame.raw[hand].extend(rr)
        self.lead = {}
        out = self.close()
        self.held = [frame]
        return out

    def close(self) -> list:
        out = [self.finish(self.held[0]), *self.held[1:]] if self.held else []
        self.held = []
        return out
