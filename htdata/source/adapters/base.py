"""The adapter contract (docs/INGEST.md "Adapters"): what every source adapter gives the ingest.

An adapter turns one source format into `EpisodeRef`s (cheap, picklable,
found by `discover`) and `EpisodeStreams` (opened per episode, streaming
RGB frames and tactile rows on demand). Most adapters subclass
`FileDiscovery`, which finds episodes one source file at a time.

Beside it, one idea a module: discovery.py (per-file discovery, episode
ids, fingerprints), sourcetree.py (which files an adapter may read),
params.py (declared `[adapter.params]`), streamchecks.py (the grid check,
the length note, the episode-video iterator), npzrows.py (row reads from an
.npz member), video.py (probing and decoding); the registry of adapters is
htdata/source/adapters/__init__.py.

Imports inside functions: `__getattr__` hands on the helpers that lived here
before they had modules of their own, with a DeprecationWarning, until
htdata/_moved.py's REMOVED_IN.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Protocol, runtime_checkable

import numpy as np

from htdata.errors import EpisodeError
from htdata.source.adapters.discovery import discover_all
from htdata.source.adapters.sourcetree import check_source_file


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

    Args:
        ref: the episode discovery found (kept as `self.ref`, named by every error).
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
        """The episode's RGB frames in file order, decoded one at a time.

        Yields:
            (index into `rgb_timestamps_ns`, HxWx3 uint8 RGB); nothing when `has_video` is False.

        Raises:
            EpisodeError: a frame that does not decode (naming `self.ref`).
        """

    @abc.abstractmethod
    def read_tactile(self, hand: str, indices: np.ndarray) -> np.ndarray:
        """Rows of one hand's glove stream, as recorded.

        Args:
            hand: "left" or "right", a key of `tactile_timestamps_ns`.
            indices: (K,) positions into `tactile_timestamps_ns[hand]`, any order.

        Returns:
            (K, H, W) raw glove units in the source's dtype, row k for indices[k].

        Raises:
            EpisodeError: no stream for `hand` (`_check_hand`), or rows that do not read.
        """

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
    """What the ingest calls on a source format (`ADAPTERS` in adapters/__init__.py); `name` is its key."""

    name: str

    def discover(self, root: Path, params: dict) -> list[EpisodeRef]:
        """Every episode under `root`, or the first failure raised.

        Args:
            root: the source folder.
            params: the pipeline's `[adapter.params]` (declared in the adapter's PARAMS).

        Returns:
            The episodes found, sorted naturally by episode id.

        Raises:
            EpisodeError: a file or episode that could not be discovered.
        """

    def discover_all(self, root: Path, params: dict) -> tuple[list[EpisodeRef], list[EpisodeError]]:
        """Every episode under `root` that can be discovered, and one failure per one that cannot.

        Args:
            root: the source folder.
            params: the pipeline's `[adapter.params]`.

        Returns:
            (episodes sorted naturally by id, failures): a bad file fails alone, never the source.
        """

    def open(self, ref: EpisodeRef, params: dict) -> EpisodeStreams:
        """Open one discovered episode for reading (in a worker: `ref` was pickled).

        Args:
            ref: an episode this adapter's discovery returned.
            params: the pipeline's `[adapter.params]`.

        Returns:
            The episode's streams, timestamps filled; the caller closes them.

        Raises:
            EpisodeError: the episode's files do not open or disagree with `ref`.
        """


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
    recording_files: str   # what discovery_files looks for, in a user's words ("OpenTouch HDF5 files (*.hdf5)")

    def discovery_context(self, root: Path, params: dict):
        """What every file's discovery shares (an annotation table, a split file); read once per source.

        Args:
            root: the source folder.
            params: the pipeline's `[adapter.params]`.

        Returns:
            Anything `discover_file` takes as `context` (None here: nothing shared). An exception
            raised here fails the whole source.
        """
        return None

    @abc.abstractmethod
    def discovery_files(self, root: Path, params: dict) -> list[Path]:
        """The files under `root` that each hold one or more episodes (sourcetree.walk_source lists them).

        Args:
            root: the source folder.
            params: the pipeline's `[adapter.params]`.

        Returns:
            The files, in a stable order; empty when the source holds none of this format.
        """

    @abc.abstractmethod
    def discover_file(self, path: Path, root: Path, params: dict, context) -> list[EpisodeRef]:
        """The episodes of one file, from its metadata only (no frame decoded).

        Args:
            path: one of `discovery_files`.
            root: the source folder (episode ids and source refs are relative to it).
            params: the pipeline's `[adapter.params]`.
            context: what `discovery_context` returned.

        Returns:
            The file's episodes (ids through discovery.sanitise_id, fingerprints from discovery.fingerprint_files).

        Raises:
            Exception: any error for a file that cannot be read; `discover_all` makes it that file's failure.
        """

    def discover_all(self, root: Path, params: dict) -> tuple[list[EpisodeRef], list[EpisodeError]]:
        """Run `discover_file` on every file, a failing file reported and the rest discovered (discovery.py).

        Args:
            root: the source folder.
            params: the pipeline's `[adapter.params]`.

        Returns:
            (episodes sorted naturally by id, one EpisodeError per file or duplicate episode id that failed).
        """
        return discover_all(self, root, params)

    def discover(self, root: Path, params: dict) -> list[EpisodeRef]:
        """Strict form: every ref, or the first file's failure raised.

        Args:
            root: the source folder.
            params: the pipeline's `[adapter.params]`.

        Returns:
            The episodes, sorted naturally by id.

        Raises:
            EpisodeError: the first failure `discover_all` found.
        """
        refs, failures = self.discover_all(root, params)
        if failures:
            raise failures[0]
        return refs


def __getattr__(name: str):
    from htdata._moved import moved_name  # lazy: see the docstring

    return moved_name(__name__, name)
