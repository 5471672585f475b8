"""A glove's own rest: a per-cell rest reference pooled over the glove's recordings (issue 43).

One recording cannot always show a cell's rest: a grip held through a whole short recording sits
above it from the first frame to the last, and a rest read from that recording (each cell's low
percentile, the raw-count default) takes the grip for rest. The glove's other recordings can show
it: a cell's rest in a recording is its REST_PERCENTILE percentile on the no-pressure side, read with
the glove's common wander within the recording taken out (`recording_rest`), and the glove's
reference is the median of that over its recordings, so a grip held in a minority of them does not
move it.

Assumes the per-cell offsets are stable between recordings (a glove's cells keep their offsets
from one session to the next; what moves, the whole glove's level, is the common-mode shift that
baseline = "shift" fits per recording: htdata.glove.baselinefit). Needs at least MIN_RECORDINGS
recordings, more than half of them with each cell at rest at least REST_PERCENTILE % of the time.

Stored as a taxel calibration file (`offset` = the reference in raw counts, `gain` = 1 per cell:
htdata.glove.restlevel.load_taxel_calibration), so a pipeline names it as `taxel_calibration`,
the ingest verifies its sha256 and every episode record carries the arrays it was normalised with
(a recalibrated glove is a new file, a new sha256, and `htdata renormalise` the new version).
`htdata layouts rest` writes one from recordings.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic
from htdata.glove.activity import WANDER_BLOCK
from htdata.glove.commonmode import rows_common_mode
from htdata.glove.glovevalue import is_inverted
from htdata.glove.restlevel import nan_quiet, nanpercentile_columns

REST_PERCENTILE = 10.0
MIN_RECORDINGS = 3


def recording_rest(rows: np.ndarray, convention: str, q: float = REST_PERCENTILE) -> np.ndarray:
    """(H,W) each cell's rest in one recording's raw rows (T,H,W): its `q` percentile on the no-pressure
    side (the (100 - q) percentile of a glove whose counts fall with pressure) with the glove's common wander
    taken out, at the recording's common rest level; NaN for a cell never finite.

    The wander comes out first (htdata.glove.commonmode, on the calmest cells): a cell's low percentile is read
    where it rests, and a cell that rests only late in a drifting recording would otherwise take the drift
    for its own offset. The bench's glove rising 6 counts over each clip put the cells its left hands press
    up to half a count above the others that way, and a count is 7% of the press level. The recording's
    level (the median over cells of their plain `q` percentiles) is put back: without a drift the rest
    reads as before, and `shift` fits what moves the whole glove.

    Args:
        rows: (T>0,H,W) the recording's raw rows, in time order.
        convention: the glove's `value.convention` (htdata.glove.glovevalue).
        q: the percentile on the no-pressure side.
    """
    x = np.asarray(rows, np.float64)
    if x.ndim != 3 or len(x) == 0:
        raise ArgumentError(f"recording_rest: expected raw rows (T>0,H,W), got shape {x.shape}")
    sign = -1.0 if is_inverted(convention) else 1.0        # counts toward pressure: the no-pressure side is low
    flat = sign * np.where(np.isfinite(x), x, np.nan).reshape(len(x), -1)
    with nan_quiet():
        plain = nanpercentile_columns(flat, q)
        steady = nanpercentile_columns(flat - rows_common_mode(flat, WANDER_BLOCK)[:, None], q)
        seen = np.isfinite(plain)
        rest = steady + (np.median(plain[seen] - steady[seen]) if seen.any() else 0.0)
    return np.asarray(sign * rest, np.float32).reshape(x.shape[1:])


def pooled_reference(rests: list[np.ndarray], minimum: int = MIN_RECORDINGS) -> np.ndarray:
    """(H,W) the median over recordings of each cell's rest; a cell no recording saw gets the median of the
    others (it reads as NaN when it is one anyway). ArgumentError with fewer than `minimum` recordings."""
    if len(rests) < minimum:
        raise ArgumentError(f"a rest reference pools at least {minimum} recordings of the glove, got {len(rests)}: "
                            f"one recording cannot tell a grip held through it from rest")
    shapes = {np.shape(r) for r in rests}
    if len(shapes) != 1:
        raise ArgumentError(f"recordings of one glove must share a grid, got {sorted(shapes)}")
    with nan_quiet():
        ref = np.nanmedian(np.stack(rests).astype(np.float64), axis=0)
    seen = np.isfinite(ref)
    if not seen.any():
        raise ArgumentError("no cell of the glove held a finite value in any recording")
    ref[~seen] = np.median(ref[seen])
    return ref.astype(np.float32)


def rest_reference_bytes(reference: np.ndarray) -> bytes:
    """The reference as a taxel calibration .npz (offset = reference, gain = 1)."""
    ref = np.asarray(reference, np.float32)
    if ref.ndim != 2 or not np.isfinite(ref).all():
        raise ArgumentError(f"a rest reference is a finite (H,W) grid, got shape {ref.shape}")
    buf = io.BytesIO()
    np.savez(buf, offset=ref, gain=np.ones_like(ref))
    return buf.getvalue()


def write_rest_reference(path: str | Path, reference: np.ndarray) -> None:
    """Write the reference where a pipeline's `taxel_calibration` can name it (complete or not at all)."""
    write_bytes_atomic(path, rest_reference_bytes(reference))
