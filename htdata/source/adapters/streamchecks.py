"""What an opened episode checks while it streams: the tactile grid against the hand's layout and a
stream's declared length (MAX_STREAM_ROWS), the note for streams of different lengths, and the
episode-video iterator whose failures name the frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from htdata.errors import EpisodeError
from htdata.glove.layouts import load_layout
from htdata.source.adapters.base import EpisodeRef
from htdata.source.adapters.video import VideoError, iter_video_rgb

ANY_GRID = "*"   # a ref.layout_files value: read the hand's rows whatever their grid (check_tactile_shape)
# Most rows one stream of an episode may declare: 70 min of a 2 kHz glove, 23 h at 100 Hz. Checked from the
# header before a timestamp is read: planning holds ~17 bytes per row (timestamps, their pairing), so a
# forged 54 MB npz of 21M deflated rows would otherwise cost GBs before the per-sample row cap applies.
MAX_STREAM_ROWS = 1 << 23


def check_stream_rows(ref: EpisodeRef, what: str, rows: int, file: Path | str) -> None:
    """Raise EpisodeError (naming `file`) when a stream declares more than MAX_STREAM_ROWS rows."""
    if rows > MAX_STREAM_ROWS:
        raise EpisodeError(ref, None, f"{what} declares {rows} rows, more than one episode's stream may hold "
                           f"({MAX_STREAM_ROWS}, {MAX_STREAM_ROWS / 2000 / 60:.0f} min at 2 kHz): refused before "
                           f"reading (split the recording)", file=file)


def check_tactile_shape(ref: EpisodeRef, hand: str, shape: tuple[int, ...], file: Path | str) -> None:
    """Raise EpisodeError unless `shape` is (M, H, W) with (H, W) = the hand's layout grid and M at most
    MAX_STREAM_ROWS (`check_stream_rows`: call it with the header's shape, before reading a row).

    The layout is the one planning resolved (`ref.layout_files`, pipeline
    override applied), else the adapter's own `ref.layouts` entry; parsed
    layouts are cached per file version by `htdata.glove.layouts.load_layout`.
    A `layout_files` entry ANY_GRID skips the check: the caller reads rows no
    layout describes yet (`htdata layouts suggest`).
    """

    if len(shape):
        check_stream_rows(ref, f"{hand} tactile stream", int(shape[0]), file)
    if ref.layout_files.get(hand) == ANY_GRID:
        return
    layout_id = ref.layout_files.get(hand) or ref.layouts[hand]
    try:
        grid = tuple(load_layout(layout_id).grid)
    except (FileNotFoundError, ValueError, KeyError) as exc:
        raise EpisodeError(ref, None, f"{hand} hand layout {layout_id!r} cannot be loaded: {exc}", file=file) from exc
    if len(shape) != 3 or tuple(shape[1:]) != grid:
        raise EpisodeError(ref, None, f"{hand} tactile grid shape {tuple(shape)} does not match layout "
                           f"{layout_id!r} grid {grid} (expected (M, {grid[0]}, {grid[1]}))", file=file)


# Two descriptions of one stream that disagree by this factor or more describe different recordings (a
# wrong timestamps file, a cut video): the note becomes a warning the ingest prints, not only records.
MISMATCH_WARN_RATIO = 2


def file_frame_mismatch_note(what_a: str, n_a: int, what_b: str, n_b: int) -> str | None:
    """Note text for a length mismatch aligned on the shortest stream (None when equal); a "warning:" one
    (printed by the ingest) when one count is MISMATCH_WARN_RATIO times the other or more."""
    if n_a == n_b:
        return None
    more, less, d = (what_a, what_b, n_a - n_b) if n_a > n_b else (what_b, what_a, n_b - n_a)
    text = f"{more} has {d} frame{'s' if d != 1 else ''} more than {less}: aligned on shortest ({min(n_a, n_b)})"
    if max(n_a, n_b) >= MISMATCH_WARN_RATIO * max(min(n_a, n_b), 1):
        ratio = max(n_a, n_b) / max(min(n_a, n_b), 1)
        return f"warning: {text}; {ratio:.0f}x apart, so they may not describe the same recording"
    return text


def iter_episode_video(ref: EpisodeRef, video: Path, n_frames: int) -> Iterator[tuple[int, np.ndarray]]:
    """(index, RGB frame) for the first `n_frames` frames of `video` (the aligned length).

    A decode error or a video shorter than promised becomes an EpisodeError
    naming the file, the episode and the frame.
    """
    count = 0
    try:
        for frame in iter_video_rgb(video):
            if count >= n_frames:
                break
            yield count, frame
            count += 1
    except VideoError as exc:
        raise EpisodeError(ref, exc.frame, str(exc), file=video) from exc
    if count < n_frames:
        raise EpisodeError(ref, count, f"video decoded only {count} of {n_frames} frames", file=video)
