"""Adapter contract (docs/DESIGN.md "Adapters") and helpers shared by adapters.

An adapter turns one source format into `EpisodeRef`s (cheap, picklable,
found by `discover`) and `EpisodeStreams` (opened per episode, streaming
RGB frames and tactile rows on demand). Helpers here: stable episode ids,
source fingerprints, forward row reads from an .npz member without
loading it, and H.264 timestamp probing / streaming decode.
"""

from __future__ import annotations

import abc
import functools
import hashlib
import os
import re
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Protocol, runtime_checkable

import numpy as np

from htdata.errors import EpisodeError

HANDS = ("left", "right")


@dataclass
class EpisodeRef:
    """One discovered episode: found from metadata only, picklable."""

    episode_id: str          # [A-Za-z0-9_-]+, unique in a dataset, stable across runs
    source: str              # adapter name
    source_ref: str          # "<file or folder>" or "<file>::<group>"
    task: str
    scene: str
    hands: tuple[str, ...]   # ("right",) or ("left", "right")
    layouts: dict[str, str]  # hand -> layout id
    est_frames: int          # from metadata, no frame decoded
    fingerprint: str         # sha1 of (relative path, size, mtime_ns) of every source file read
    extra: dict = field(default_factory=dict)


class EpisodeStreams(abc.ABC):
    """An opened episode. Subclasses fill the timestamps and implement the readers.

    `rgb_timestamps_ns` (N,) int64 and `tactile_timestamps_ns` {hand: (M_h,)}
    are as recorded (may be unsorted/duplicated; sync cleans them).
    `iter_rgb` yields (rgb index, HxWx3 uint8 RGB) in file order, streamed;
    `read_tactile(hand, indices)` returns (len, H, W) float32 raw glove units.
    """

    def __init__(self, ref: EpisodeRef):
        self.ref = ref
        self.rgb_timestamps_ns: np.ndarray = np.zeros(0, dtype=np.int64)
        self.tactile_timestamps_ns: dict[str, np.ndarray] = {}
        self.notes: list[str] = []

    @abc.abstractmethod
    def iter_rgb(self) -> Iterator[tuple[int, np.ndarray]]:
        ...

    @abc.abstractmethod
    def read_tactile(self, hand: str, indices: np.ndarray) -> np.ndarray:
        ...

    def close(self) -> None:
        """Release open files; safe to call twice."""

    def _setup_or_close(self, setup) -> None:
        """Run `setup()`; on any failure release what it opened, then re-raise."""
        try:
            setup()
        except Exception:
            self.close()
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_hand(self, hand: str) -> None:
        if hand not in self.tactile_timestamps_ns:
            raise EpisodeError(self.ref, None, f"no tactile stream for hand {hand!r} (has {sorted(self.tactile_timestamps_ns)})")


@runtime_checkable
class Adapter(Protocol):
    name: str

    def discover(self, root: Path, params: dict) -> list[EpisodeRef]: ...

    def discover_all(self, root: Path, params: dict) -> tuple[list[EpisodeRef], list[EpisodeError]]: ...

    def open(self, ref: EpisodeRef, params: dict) -> EpisodeStreams: ...


# --------------------------------------------------------------------------
# discovery: one source file at a time, so one bad file never hides the rest


class FileDiscovery(abc.ABC):
    """Discovery split per source file; adapters subclass this and fill three hooks.

    `discovery_context(root, params)` reads what the whole source shares
    (annotation table, split file, params); an error there aborts the
    source. `discovery_files(root, params)` lists the files that each hold
    one or more episodes (HDF5 scenes, npz grids, recording.json), and
    `discover_file(path, root, params, context)` turns one of them into refs,
    raising when the file is unreadable. `discover_all` runs the per-file
    hook under the one try/except that turns a bad file into a failure.
    """

    name: str

    def discovery_context(self, root: Path, params: dict):
        return None

    @abc.abstractmethod
    def discovery_files(self, root: Path, params: dict) -> list[Path]:
        ...

    @abc.abstractmethod
    def discover_file(self, path: Path, root: Path, params: dict, context) -> list[EpisodeRef]:
        ...

    def discover_all(self, root: Path, params: dict) -> tuple[list[EpisodeRef], list[EpisodeError]]:
        return discover_all(self, root, params)

    def discover(self, root: Path, params: dict) -> list[EpisodeRef]:
        """Strict form: every ref, or the first file's failure raised."""
        refs, failures = self.discover_all(root, params)
        if failures:
            raise failures[0]
        return refs


def discovery_failure(path: Path, exc: BaseException) -> EpisodeError:
    """`exc` raised while discovering `path` as an EpisodeError naming the file (and episode when known)."""
    if isinstance(exc, EpisodeError):
        if exc.file is not None:
            return exc
        return EpisodeError(None, exc.frame, exc.message, file=path, episode_id=exc.episode_id)
    return EpisodeError(None, None, f"{type(exc).__name__}: {exc}", file=path)


def discover_all(adapter: FileDiscovery, root: Path | str, params: dict) -> tuple[list[EpisodeRef], list[EpisodeError]]:
    """(refs sorted naturally by episode id, one EpisodeError per file or episode that failed).

    A file that raises while being read becomes a failure and every other
    file is still discovered; an episode id already produced by an earlier
    file is a failure of the later one (the first keeps the id).
    """
    root = Path(root)
    context = adapter.discovery_context(root, params)
    refs: list[EpisodeRef] = []
    failures: list[EpisodeError] = []
    seen: dict[str, str] = {}
    for path in adapter.discovery_files(root, params):
        try:
            found = adapter.discover_file(path, root, params, context)
        except Exception as exc:  # any unreadable file is reported, never fatal for the source
            failures.append(discovery_failure(path, exc))
            continue
        for ref in found:
            if ref.episode_id in seen:
                failures.append(EpisodeError(None, None, f"episode id {ref.episode_id} also produced by "
                                             f"{seen[ref.episode_id]}", file=path, episode_id=ref.episode_id))
                continue
            seen[ref.episode_id] = ref.source_ref
            refs.append(ref)
    return sorted(refs, key=lambda r: natural_key(r.episode_id)), failures


# --------------------------------------------------------------------------
# ids and fingerprints

_UNSAFE = re.compile(r"[^A-Za-z0-9_-]+")


def sanitise_id(text: str) -> str:
    """Map any text onto [A-Za-z0-9_-]+ (runs of other characters -> '_')."""
    out = _UNSAFE.sub("_", text).strip("_")
    if not out:
        raise ValueError(f"cannot make an episode id from {text!r}")
    return out


def natural_key(text: str) -> tuple:
    """Sort key comparing digit runs as numbers: demo_2 < demo_10, demo_007 == 7."""
    return tuple((0, int(tok), tok) if tok.isdigit() else (1, 0, tok) for tok in re.findall(r"\d+|\D+", text))


def fingerprint_files(root: Path, files: Iterable[Path]) -> str:
    """sha1 over (path relative to root, size, mtime_ns) of the files, in sorted order."""
    h = hashlib.sha1()
    root = Path(root)
    for path in sorted(Path(p) for p in files):
        st = path.stat()
        try:
            rel = path.relative_to(root).as_posix()
        except ValueError:
            rel = path.as_posix()
        h.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


@functools.lru_cache(maxsize=64)
def _cached_layout_grid(path: str, mtime_ns: int, size: int) -> tuple[int, ...]:
    from htdata.layouts import load_layout

    return tuple(load_layout(path).grid)


def layout_grid(layout_id: str) -> tuple[int, ...]:
    """Raw grid (H, W) of a layout id or file, parsed (and schema-checked) once per file version.

    Opening an episode checks its grids against the layout; parsing and
    validating the layout JSON each time was a visible per-episode cost.
    """
    from htdata.layouts import layout_path, load_layout

    path = layout_path(layout_id)
    try:
        st = path.stat()
    except OSError:
        return tuple(load_layout(layout_id).grid)   # raises FileNotFoundError naming the layout
    return _cached_layout_grid(str(path), st.st_mtime_ns, st.st_size)


def check_tactile_shape(ref: EpisodeRef, hand: str, shape: tuple[int, ...], file: Path | str) -> None:
    """Raise EpisodeError unless `shape` is (M, H, W) with (H, W) = the hand's layout grid."""
    layout_id = ref.layouts[hand]
    try:
        grid = layout_grid(layout_id)
    except (FileNotFoundError, ValueError, KeyError) as exc:
        raise EpisodeError(ref, None, f"{hand} hand layout {layout_id!r} cannot be loaded: {exc}", file=file) from exc
    if len(shape) != 3 or tuple(shape[1:]) != grid:
        raise EpisodeError(ref, None, f"{hand} tactile grid shape {tuple(shape)} does not match layout "
                           f"{layout_id!r} grid {grid} (expected (M, {grid[0]}, {grid[1]}))", file=file)


# --------------------------------------------------------------------------
# forward row reads from one .npy member of an .npz


class NpzRowError(Exception):
    """A row of an npz member could not be read (`row` is the first bad row, or None)."""

    def __init__(self, row: int | None, message: str):
        self.row = row
        super().__init__(message)


_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError)


def _read_npy_header(stream) -> tuple[tuple[int, ...], bool, np.dtype]:
    from numpy.lib import format as npy

    version = npy.read_magic(stream)
    if version == (1, 0):
        return npy.read_array_header_1_0(stream)
    if version == (2, 0):
        return npy.read_array_header_2_0(stream)
    raise NpzRowError(None, f"unsupported .npy format version {version}")


class NpzRows:
    """Rows `arr[i]` of the array `key` in an .npz, read sequentially from the zip member.

    Works for stored and deflated members: the member is decompressed as a
    stream, rows before a requested one are read and discarded in chunks,
    and an index below the current position reopens the member. Never holds
    more than `chunk_rows` rows beyond the result.
    """

    def __init__(self, npz_path: Path | str, key: str, *, chunk_rows: int = 256):
        self.path = Path(npz_path)
        self.member = f"{key}.npy"
        self.chunk_rows = max(1, int(chunk_rows))
        try:
            self._zip = zipfile.ZipFile(self.path)
        except _ZIP_ERRORS as exc:
            raise NpzRowError(None, f"not a readable npz ({exc})") from exc
        if self.member not in self._zip.namelist():
            self._zip.close()
            raise NpzRowError(None, f"npz has no array {key!r} (has {sorted(n[:-4] for n in self._zip.namelist())})")
        self._stream = None
        self._next_row = 0
        self._open_member()

    @property
    def num_rows(self) -> int:
        return int(self.shape[0]) if self.shape else 1

    def _open_member(self) -> None:
        if self._stream is not None:
            self._stream.close()
        try:
            self._stream = self._zip.open(self.member)
            shape, fortran, dtype = _read_npy_header(self._stream)
        except _ZIP_ERRORS as exc:
            raise NpzRowError(None, f"{self.member}: bad .npy header ({exc})") from exc
        if dtype.hasobject:
            raise NpzRowError(None, f"{self.member}: object arrays are not supported")
        if fortran and len(shape) > 1:
            raise NpzRowError(None, f"{self.member}: Fortran-ordered arrays cannot be read row by row")
        self.shape, self.dtype = tuple(shape), dtype
        self.row_shape = self.shape[1:]
        self.row_bytes = int(np.prod(self.row_shape, dtype=np.int64)) * dtype.itemsize
        self._next_row = 0

    def _read_block(self, n: int) -> np.ndarray:
        want = n * self.row_bytes
        try:
            data = self._stream.read(want)
        except _ZIP_ERRORS as exc:
            raise NpzRowError(self._next_row, f"{self.member}: data does not decompress ({exc})") from exc
        if len(data) != want:
            got = len(data) // max(self.row_bytes, 1)
            raise NpzRowError(self._next_row + got, f"{self.member}: truncated, ends at row {self._next_row + got} "
                              f"of {self.num_rows}")
        self._next_row += n
        return np.frombuffer(data, dtype=self.dtype).reshape((n,) + self.row_shape)

    def _skip_to(self, row: int) -> None:
        while self._next_row < row:
            self._read_block(min(self.chunk_rows, row - self._next_row))

    def read(self, indices) -> np.ndarray:
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        out = np.empty((idx.size,) + self.row_shape, dtype=self.dtype)
        if idx.size == 0:
            return out
        if idx.min() < 0 or idx.max() >= self.num_rows:
            raise NpzRowError(int(idx.min() if idx.min() < 0 else idx.max()),
                              f"{self.member}: row index out of range 0..{self.num_rows - 1}")
        order = np.argsort(idx, kind="stable")
        wanted = idx[order]
        if wanted[0] < self._next_row:
            self._open_member()
        pos = 0
        while pos < wanted.size:
            start = int(wanted[pos])
            self._skip_to(start)
            stop = min(int(wanted[-1]) + 1, start + self.chunk_rows)
            block = self._read_block(stop - start)
            end = pos + int(np.searchsorted(wanted[pos:], stop, side="left"))
            out[order[pos:end]] = block[wanted[pos:end] - start]
            pos = end
        return out

    def read_all(self) -> np.ndarray:
        """Whole member (for small arrays such as timestamps)."""
        return self.read(np.arange(self.num_rows))

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
            self._stream = None
        self._zip.close()


def npz_member_shape(npz_path: Path | str, key: str) -> tuple[int, ...]:
    """Shape of one npz member from its .npy header (no data read)."""
    rows = NpzRows(npz_path, key)
    try:
        return rows.shape
    finally:
        rows.close()


# --------------------------------------------------------------------------
# video


class VideoError(Exception):
    """A video cannot be opened/decoded (`frame` = first bad frame, or None)."""

    def __init__(self, frame: int | None, message: str):
        self.frame = frame
        super().__init__(message)


def _av_errors() -> tuple[type[BaseException], ...]:
    import av

    return (av.FFmpegError, OSError, ValueError, EOFError)


def probe_video_pts_ns(path: Path | str) -> np.ndarray:
    """Presentation times (ns from the first frame), sorted = decode output order.

    Reads packets only (no decoding), so it is cheap even for long videos.
    """
    import av

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
    """Single-threaded (by default) slice decoding for `stream`; set before the first packet."""
    stream.thread_type = "SLICE"
    stream.codec_context.thread_count = int(threads)


def iter_video_rgb(path: Path | str) -> Iterator[np.ndarray]:
    """Decode a video frame by frame as HxWx3 uint8 RGB (presentation order).

    Packets are decoded one by one so that a corrupt packet in the middle of
    the file is named by its own presentation index (`VideoError.frame`):
    the decoder holds a few frames back for reordering, so the count of
    frames delivered so far would point a little before it.
    """
    import av

    count = 0
    try:
        container = av.open(str(path))
    except _av_errors() as exc:
        raise VideoError(None, f"video does not open ({exc})") from exc
    try:
        if not container.streams.video:
            raise VideoError(None, "video has zero frames (no video stream in the container)")
        stream = container.streams.video[0]
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
                raise VideoError(bad, f"video frame does not decode: corrupt packet at frame {bad}, "
                                 f"{count} frames decoded before it ({exc})") from exc
            for frame in frames:
                yield frame.to_ndarray(format="rgb24")
                count += 1
    finally:
        container.close()


def file_frame_mismatch_note(what_a: str, n_a: int, what_b: str, n_b: int) -> str | None:
    """Note text for a length mismatch aligned on the shortest stream (None when equal)."""
    if n_a == n_b:
        return None
    more, less, d = (what_a, what_b, n_a - n_b) if n_a > n_b else (what_b, what_a, n_b - n_a)
    return f"{more} has {d} frame{'s' if d != 1 else ''} more than {less}: aligned on shortest ({min(n_a, n_b)})"


def relpath_inside(folder: Path, rel: str, where: str) -> Path:
    """Resolve `rel` under `folder`, refusing paths that escape it."""
    path = (folder / rel).resolve()
    if os.path.commonpath([path, folder.resolve()]) != str(folder.resolve()):
        raise ValueError(f"{where}: path {rel!r} leaves the recording folder")
    return path


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
