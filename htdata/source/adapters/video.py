"""Video helpers shared by adapters: packet timestamps (no decode) and streaming RGB decode."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from htdata.source.adapters.mp4header import Mp4HeaderError, check_mp4_header
from htdata.source.rgb import MAX_SOURCE_FRAME_PIXELS, frame_size_error


class VideoError(Exception):
    """A video cannot be opened/decoded (`frame` = first bad frame, or None)."""

    def __init__(self, frame: int | None, message: str):
        self.frame = frame
        super().__init__(message)


def check_declared(path: Path | str, frame: int | None = 0) -> None:
    """The file's declared sizes, from its MP4 boxes, before FFmpeg opens it (htdata/source/adapters/mp4header.py)."""
    try:
        check_mp4_header(path, MAX_SOURCE_FRAME_PIXELS)
    except Mp4HeaderError as exc:
        raise VideoError(frame, f"video {exc}") from None
    except OSError as exc:
        raise VideoError(None, f"video does not open ({exc})") from exc


def _av_errors() -> tuple[type[BaseException], ...]:
    import av

    return (av.FFmpegError, OSError, ValueError, EOFError)


def probe_video_pts_ns(path: Path | str) -> np.ndarray:
    """Presentation times (ns from the first frame), sorted = decode output order.

    Reads packets only (no decoding), so it is cheap even for long videos.
    """
    import av

    check_declared(path, None)
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise VideoError(None, "video has zero frames (no video stream in the container)")
            stream = container.streams.video[0]
            tb = stream.time_base
            pts = [p.pts for p in container.demux(stream) if p.pts is not None and p.size > 0]
    except _av_errors() as exc:
        raise VideoError(None, f"video does not open ({exc})") from exc
    if not pts:
        return np.zeros(0, dtype=np.int64)
    p = np.sort(np.asarray(pts, dtype=np.int64))
    p -= p[0]
    # exact rational -> ns with rounding; int64 is ample for hours of video
    return (p * tb.numerator * 1_000_000_000 + tb.denominator // 2) // tb.denominator


def _presentation_index(path: Path | str, pts: int | None, fallback: int) -> int:
    """Presentation-order index of the packet stamped `pts` (its rank among all packet pts)."""
    import av

    if pts is None:
        return fallback
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            all_pts = np.sort(np.asarray([p.pts for p in container.demux(stream) if p.pts is not None and p.size > 0],
                                        dtype=np.int64))
    except _av_errors():
        return fallback
    return int(np.searchsorted(all_pts, pts)) if all_pts.size else fallback


# Decoder threads per video stream. Ingest parallelism comes from worker
# processes (one per core); FFmpeg's default (slice threads, count = cores)
# made decode wall time 2-3x its CPU time on a loaded 2-core machine, and
# H.264 decoding is bit-exact whatever the thread count.
VIDEO_DECODE_THREADS = 1


def configure_decoder_threads(stream, threads: int = VIDEO_DECODE_THREADS) -> None:
    """Single-threaded (by default) slice decoding for `stream`, and FFmpeg's own frame-size limit
    (`max_pixels`: the decoder refuses to allocate a larger picture, so a stream that switches to a
    12000x12000 SPS mid-way fails at that frame instead of costing ~1 GB); set before the first packet."""
    stream.thread_type = "SLICE"
    stream.codec_context.thread_count = int(threads)
    stream.codec_context.options = {"max_pixels": str(MAX_SOURCE_FRAME_PIXELS)}


def iter_video_rgb(path: Path | str) -> Iterator[np.ndarray]:
    """Decode a video frame by frame as HxWx3 uint8 RGB (presentation order).

    Packets are decoded one by one so that a corrupt packet in the middle of
    the file is named by its own presentation index (`VideoError.frame`):
    the decoder holds a few frames back for reordering, so the count of
    frames delivered so far would point a little before it.

    Damage the decoder conceals instead of reporting (e.g. 3000 bytes of
    0xFF inside an H.264 slice: no error, a smeared picture) is caught by
    FFmpeg's per-frame corrupt flag (AV_FRAME_FLAG_CORRUPT, `is_corrupt`):
    such a frame raises VideoError naming its presentation index, so a
    damaged file fails its episode instead of ingesting smeared frames.
    """
    import av

    count = 0
    check_declared(path)
    try:
        container = av.open(str(path))
    except _av_errors() as exc:
        raise VideoError(None, f"video does not open ({exc})") from exc
    try:
        if not container.streams.video:
            raise VideoError(None, "video has zero frames (no video stream in the container)")
        stream = container.streams.video[0]
        why = frame_size_error(int(stream.codec_context.height or 1), int(stream.codec_context.width or 1))
        if why:   # the decoder would allocate every frame at that size
            raise VideoError(0, f"video stream {why}")
        configure_decoder_threads(stream)
        packets = container.demux(stream)
        while True:
            try:
                packet = next(packets)
            except StopIteration:
                return
            except _av_errors() as exc:
                raise VideoError(count, f"video stream unreadable after {count} frames ({exc})") from exc
            try:
                frames = packet.decode()  # the final empty packet flushes the decoder
            except _av_errors() as exc:
                bad = _presentation_index(path, packet.pts, count)
                raise VideoError(bad, f"video frame does not decode: a corrupt packet at frame {bad}, or a picture "
                                 f"over the {MAX_SOURCE_FRAME_PIXELS / 1e6:.1f} Mpx a source frame may hold; "
                                 f"{count} frames decoded before it ({exc})") from exc
            for frame in frames:
                why = frame_size_error(int(frame.height), int(frame.width))
                if why:   # a size changed mid-stream: refused before the RGB copy of it
                    raise VideoError(count, f"video frame {count} {why}")
                if frame.is_corrupt:
                    raise VideoError(count, f"video frame {count} is damaged: the decoder concealed corrupt "
                                     f"data (corrupt-frame flag set), {count} frames decoded before it")
                yield frame.to_ndarray(format="rgb24")
                count += 1
    finally:
        container.close()
