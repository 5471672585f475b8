"""One chunk of synchronised frames read from the glove: rows decoded, checked, normalised, kept or dropped.

`read_chunk` reads every hand's rows for sync positions [start, stop) in one
call per hand (paired rows and the unpaired rows those frames carry, so
streamed sources never rewind), checks their shape against the layout,
normalises them, drops frames with non-finite live taxels and applies the
pipeline's out-of-range policy. `frame_raw_rows` hands each kept frame the
raw rows its sample stores. Used by htdata/ingest/episode.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from htdata.errors import EpisodeError
from htdata.ingest.fullrate import RawRows
from htdata.ingest.tally import EpisodeTally
from htdata.ingest.timing import StageClock


@dataclass
class ChunkRawRows:
    """One hand's raw rows read for a chunk of synchronised frames (keep_raw): what the samples will store.

    `paired[j]` / `paired_times[j]` is frame j's paired row; `extra` are the unpaired source rows the
    chunk's frames carry, `slots` the frame (sync position) each belongs to, with their values and times.
    """
    paired: np.ndarray          # (n,H,W) source dtype
    paired_times: np.ndarray    # (n,) ns, as recorded
    extra: np.ndarray           # (m,) source row numbers
    slots: np.ndarray           # (m,) sync positions, increasing
    extra_values: np.ndarray    # (m,H,W)
    extra_times: np.ndarray     # (m,) ns


def read_chunk(ref, streams, tally: EpisodeTally, normalisers: dict, start: int, stop: int,
                clock: StageClock, plans: dict) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, ChunkRawRows]]:
    """Normalised values of every hand for sync rows [start, stop), the mask of frames kept, and the raw rows.

    Raw rows (when `plans` has the hand: keep_raw) = {hand: ChunkRawRows}, read in ONE call with the
    paired rows so streamed sources never rewind.
    """
    sync = tally.sync
    rgb_idx = sync.rgb_index[start:stop]
    ok = np.ones(stop - start, dtype=bool)
    values, raws = {}, {}
    for h in tally.hands:
        layout = tally.layouts[h]
        paired = sync.tactile_index[h][start:stop]
        extra, slots = plans[h].rows_for(start, stop) if h in plans else (np.zeros(0, np.int64), None)
        uniq, inverse = np.unique(np.concatenate([paired, extra]), return_inverse=True)  # increasing rows
        with clock.stage("decode"):
            rows = np.asarray(streams.read_tactile(h, uniq))
        if rows.ndim != 3 or rows.shape[1:] != tuple(layout.grid) or rows.shape[0] != uniq.size:
            raise EpisodeError(ref, int(rgb_idx[0]), f"{h} tactile rows have shape {rows.shape}, expected "
                               f"({uniq.size}, {layout.grid[0]}, {layout.grid[1]}) for layout {layout.layout_id}")
        inverse = inverse.reshape(-1)
        raw = rows[inverse[:paired.size]]
        tally.add_raw(h, raw)
        if h in plans:
            ts = plans[h].timestamps   # as recorded (a lag the sync applied is in the sync report)
            raws[h] = ChunkRawRows(paired=raw, paired_times=ts[paired], extra=extra, slots=slots,
                                   extra_values=rows[inverse[paired.size:]], extra_times=ts[extra])
        with clock.stage("normalise"):
            if start == 0:
                normalisers[h].fit_baseline(raw)
            v, finite = normalisers[h].apply(raw, rows=paired)
            below, above = normalisers[h].out_of_range(raw)
        for j in np.flatnonzero(ok & ~finite):
            tally.dropped.append((int(rgb_idx[j]), f"nonfinite_tactile:{h}"))
        ok &= finite
        ok &= _out_of_range_policy(ref, tally, h, normalisers[h], raw, below, above, rgb_idx, ok)
        values[h] = v
    return values, ok, raws


def frame_raw_rows(sync, raws: dict[str, ChunkRawRows], start: int, j: int) -> dict[str, RawRows]:
    """The raw rows synchronised frame `start + j` brings: its paired row and the unpaired rows of its slot."""
    k = start + j
    out = {}
    for h, c in raws.items():
        rr = RawRows(paired_row=int(sync.tactile_index[h][k]))
        rr.add(rr.paired_row, int(c.paired_times[j]), c.paired[j])
        a, b = np.searchsorted(c.slots, [k, k + 1], side="left")
        for row, t, value in zip(c.extra[a:b], c.extra_times[a:b], c.extra_values[a:b]):
            rr.add(int(row), int(t), value)
        out[h] = rr
    return out


def _out_of_range_policy(ref, tally: EpisodeTally, hand: str, normaliser, raw, below, above, rgb_idx,
                         ok: np.ndarray) -> np.ndarray:
    """Count a chunk's out-of-range raw values and apply the policy; returns the mask of frames that stay."""
    bad = tally.add_out_of_range(hand, below, above)
    tally.raw_max[hand] = float(normaliser.cfg.max_value)
    policy = tally.oor_policy.policy if tally.oor_policy is not None else "clip"
    if not bad.any() or policy == "clip":
        return np.ones_like(ok)
    if policy == "fail":
        j = int(np.flatnonzero(bad)[0])
        live = raw[j][normaliser.live_mask]
        with np.errstate(invalid="ignore"):
            worst = float(live[(live < 0) | (live > np.float32(normaliser.cfg.max_value))][0])
        raise EpisodeError(ref, int(rgb_idx[j]), f"{hand} hand raw value {worst:g} outside [0, "
                           f"{normaliser.cfg.max_value:g}] (layout {normaliser.layout_id}; {int(below[j])} taxels "
                           f"below, {int(above[j])} above); pipeline [normalise] out_of_range = \"fail\"")
    for j in np.flatnonzero(ok & bad):   # drop_frame
        tally.dropped.append((int(rgb_idx[j]), f"out_of_range:{hand}"))
    return ~bad
