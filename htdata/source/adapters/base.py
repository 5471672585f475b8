"""Adapter contract (docs/INGEST.md "Adapters") and helpers shared by adapters.

An adapter turns one source format into `EpisodeRef`s (cheap, picklable,
found by `discover`) and `EpisodeStreams` (opened per episode, streaming
RGB frames and tactile rows on demand). Helpers here: per-file discovery,
stable episode ids, source fingerprints, the grid check against a layout,
the episode-video iterator, the source-tree rules every adapter follows
(`walk_source`, `check_source_file`) and declared adapter params
(`AdapterParam`, `check_adapter_params`). Row reads from an .npz member live in
`npzrows.py`, video probing/decoding in `video.py`; the registry of
adapters is `htdata/source/adapters/__init__.py`.
"""

from __future__ import annotations

import abc
import hashlib
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Protocol, runtime_checkable

import numpy as np

from htdata.errors import ConfigError
from htdata.source.adapters.video import VideoError, iter_video_rgb
from htdata.errors import EpisodeError
from htdata.glove.layouts import load_layout


@dataclass
class EpisodeRef:
    """One discovered episode: found from metadata only, picklable."""

    episode_id: str          # [A-Za-z0-9_-]+, unique in a dataset, stable across runs
    source: str              # adapter name
    source_ref: str          # "<file or folder>" or "<file>::<group>"
    task: str
    scene: str
    hands: tuple[str, ...]   # ("right",) or ("left", "right")
    layouts: dict[str, str]  # hand -> layout id (or a layout JSON path, as the source names it)
    est_frames: int          # from metadata, no frame decoded
    fingerprint: str         # sha1 of (relative path, size, mtime_ns) of every source file read
                             # (+ the resolved layout files' sha256 once planned)
    extra: dict = field(default_factory=dict)
    # hand -> absolute path of the layout JSON, set once by ingest planning (htdata.ingest.plan):
    # the pipeline's [layouts] override applied, `layouts` then holds the layout ids.
    layout_files: dict[str, str] = field(default_factory=dict)
    # every source file the episode reads (absolute paths): what ingest checksums (htdata.ingest.sourcesums)
    source_files: tuple[str, ...] = ()


class EpisodeStreams(abc.ABC):
    """An opened episode. Subclasses fill the timestamps and implement the readers.

    `rgb_timestamps_ns` (N,) int64 and `tactile_timestamps_ns` {hand: (M_h,)}
    are as recorded (may be unsorted/duplicated; sync cleans them).
    `iter_rgb` yields (rgb index, HxWx3 uint8 RGB) in file order, streamed;
    `read_tactile(hand, indices)` returns (len, H, W) raw glove units in the SOURCE dtype
    (the raw members store them bit for bit; normalisation converts to float32).
    """

    def __init__(self, ref: EpisodeRef):
        self.ref = ref
        self.rgb_timestamps_ns: np.ndarray = np.zeros(0, dtype=np.int64)
        self.tactile_timestamps_ns: dict[str, np.ndarray] = {}
        self.notes: list[str] = []
        # False: a glove-only recording; rgb_timestamps_ns is then the clock samples follow and
        # iter_rgb yields nothing (tactile-only samples, htdata.ingest.episode)
        self.has_video = True

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

    def _check_file(self, path: Path | str) -> Path:
        """Re-check at open that `path` is a regular file (discovery placed it in the tree): no FIFO blocks us."""
        try:
            return check_source_file(path, None)
        except EpisodeError as exc:
            raise EpisodeError(self.ref, None, exc.message, file=path) from exc

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
            check_source_file(path, root)
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
    """sha1 over (path relative to root, size, mtime_ns) of the files, in sorted order.

    Each file is first checked by `check_source_file` (regular, inside the
    tree): adapters list every file an episode reads here, so the rule holds
    for all of them (a FIFO named chest.mp4 is refused at discovery).
    """
    h = hashlib.sha1()
    root = Path(root)
    for path in sorted(Path(p) for p in files):
        check_source_file(path, root)   # every file an episode reads passes the source-tree rules
        st = path.stat()
        try:
            rel = path.relative_to(root).as_posix()
        except ValueError:
            rel = path.as_posix()
        h.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


ANY_GRID = "*"   # a ref.layout_files value: read the hand's rows whatever their grid (check_tactile_shape)


def check_tactile_shape(ref: EpisodeRef, hand: str, shape: tuple[int, ...], file: Path | str) -> None:
    """Raise EpisodeError unless `shape` is (M, H, W) with (H, W) = the hand's layout grid.

    The layout is the one planning resolved (`ref.layout_files`, pipeline
    override applied), else the adapter's own `ref.layouts` entry; parsed
    layouts are cached per file version by `htdata.glove.layouts.load_layout`.
    A `layout_files` entry ANY_GRID skips the check: the caller reads rows no
    layout describes yet (`htdata layouts suggest`).
    """

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


# --------------------------------------------------------------------------
# the source tree: what an adapter may read
#
# Rules (the same for every adapter): a source file must be a regular file
# (a FIFO, socket or device would block or never end: refused with a
# message); a symlink is resolved and accepted only when its target lies
# inside the source root (a link to another tree could ingest someone
# else's data silently). Directory symlinks: one pointing outside the root
# is refused (reported, not skipped); one pointing inside leads to folders
# the walk reaches anyway at their real path, so their recordings are
# ingested once, under that real path (stable source_ref, no loop, no
# episode found twice).


def _inside(path: Path, root: Path) -> bool:
    return os.path.commonpath([str(path), str(root)]) == str(root)


def check_source_file(path: Path | str, root: Path | str | None) -> Path:
    """Raise EpisodeError (naming `path`) unless it is a regular file whose real path is inside `root`.

    `root=None` checks only the file type (e.g. when an opened episode
    re-checks a file that discovery already placed). Returns the path.
    Never opens the file, so a FIFO cannot block here.
    """
    path = Path(path)
    try:
        st = os.stat(path)   # follows symlinks: the type of what would be read
    except OSError as exc:
        raise EpisodeError(None, None, f"source file cannot be read: {exc.strerror or exc}", file=path) from exc
    real = path.resolve()
    outside = root is not None and not _inside(real, Path(root).resolve())
    if outside:
        what = "directory symlink" if stat.S_ISDIR(st.st_mode) else "symlink" if path.is_symlink() else "path"
        raise EpisodeError(None, None, f"{what} leaves the source tree {root} (-> {real}): refused", file=path)
    if not stat.S_ISREG(st.st_mode):
        kind = ("FIFO" if stat.S_ISFIFO(st.st_mode) else "socket" if stat.S_ISSOCK(st.st_mode)
                else "directory" if stat.S_ISDIR(st.st_mode) else "device or special file")
        raise EpisodeError(None, None, f"not a regular file ({kind}): refused", file=path)
    return path


def walk_source(root: Path | str, match) -> list[Path]:
    """Sorted paths under `root` whose name satisfies `match(name)`, following the tree rules above.

    Real folders are walked; a directory symlink that leaves the tree is
    listed itself so that `discover_all` reports it (via
    `check_source_file`) instead of skipping it silently; one inside the
    tree is not descended (its target is walked at its real path). Matched
    files are listed whatever their type: the check that refuses FIFOs and
    outside links runs per file in `discover_all`.
    """
    root = Path(root)
    real_root = root.resolve()
    out: list[Path] = []
    for folder, dirs, files in os.walk(root):   # os.walk never descends into directory symlinks
        here = Path(folder)
        for name in dirs:
            path = here / name
            if path.is_symlink() and not _inside(path.resolve(), real_root):
                out.append(path)             # refused later, with a message
        out += [here / name for name in files if match(name)]
    return sorted(out)


# --------------------------------------------------------------------------
# adapter params: each adapter declares what [adapter.params] may hold


@dataclass(frozen=True)
class AdapterParam:
    """One `[adapter.params]` key an adapter understands."""
    name: str
    types: tuple[type, ...]   # accepted TOML value types (bool is never taken for int)
    default: object
    help: str


def param_values(declared: tuple[AdapterParam, ...], params: dict) -> dict:
    """Every declared param: its value in `params`, else its default (declared once, in PARAMS)."""
    return {**{p.name: p.default for p in declared}, **params}


def check_adapter_params(adapter: str, declared: tuple[AdapterParam, ...], params: dict, where: str) -> None:
    """Raise ValueError naming the key and listing the known params when `params` does not fit `declared`."""
    known = {p.name: p for p in declared}
    listing = ", ".join(f"{p.name} ({'/'.join(t.__name__ for t in p.types)}, default {p.default!r})"
                        for p in declared) or "none"
    for key, value in params.items():
        if key not in known:
            raise ConfigError(f"{where}: adapter.params.{key} is not a param of adapter {adapter!r}; "
                             f"known params: {listing}")
        spec = known[key]
        ok = isinstance(value, spec.types) and not (isinstance(value, bool) and bool not in spec.types)
        if not ok:
            raise ConfigError(f"{where}: adapter.params.{key} must be {'/'.join(t.__name__ for t in spec.types)} "
                             f"({spec.help}), got {type(value).__name__} {value!r}")
