"""Exceptions shared by the whole toolkit.

`EpisodeError` is what a bad recording raises: it names the file, the
episode and (when known) the frame, so a failure report points straight at
the offending input, e.g.
``home_kitchen_p3.hdf5 [ot-home_kitchen_p3-demo_07] frame 12: JPEG does not decode``.
"""

from __future__ import annotations

from pathlib import Path


class HtdataError(Exception):
    """Base class of every error htdata raises on purpose."""


# The three kinds of mistake a user can make, each also a ValueError so `except ValueError`
# written before they existed still catches them. Programming errors stay built-in.
class ConfigError(HtdataError, ValueError):
    """A setting the user wrote is invalid: a pipeline TOML, a `--set`, a layout file, a trainer
    config. The one-line message names the setting (and the file when there is one)."""


class ArgumentError(HtdataError, ValueError):
    """An argument a caller passed does not fit what it names: an unknown split or part, a sample
    index out of range, a version that does not exist, options that exclude each other."""


class DatasetError(HtdataError, ValueError):
    """A dataset (or a member of it) is not what its records say: a damaged or foreign file, bytes
    that do not decode, records that disagree. The message names the dataset file or record."""


class LayoutNotFound(HtdataError, FileNotFoundError):
    """A glove layout id or file that is on no search path; the message is one line
    naming where it looked and the layouts that exist (htdata.glove.layouts.resolve_layout)."""


class BackendMissing(HtdataError, ImportError):
    """A URL whose fsspec backend is not installed (s3:// without s3fs, ...); the message is one
    line naming the URL, the package and the htdata extra that brings it (htdata/store/storage.py)."""


class EpisodeError(HtdataError):
    """A recording (or one frame of it) cannot be read.

    Call as ``EpisodeError(ref, frame, message)`` where `ref` is an
    `EpisodeRef` (file and episode id are taken from it), or pass
    ``file=`` / ``episode_id=`` explicitly (e.g. during discovery, before
    a ref exists). Explicit keywords win over what `ref` provides.
    """

    def __init__(
        self,
        ref=None,
        frame: int | None = None,
        message: str = "",
        *,
        file: str | Path | None = None,
        episode_id: str | None = None,
    ):
        if ref is not None:
            if episode_id is None:
                episode_id = getattr(ref, "episode_id", None)
            if file is None:
                source_ref = getattr(ref, "source_ref", None)
                if source_ref:
                    file = str(source_ref).split("::", 1)[0]
        self.file = str(file) if file is not None else None
        self.episode_id = episode_id
        self.frame = None if frame is None else int(frame)
        self.message = message
        super().__init__(self._render())

    def _render(self) -> str:
        head = self.file if self.file is not None else "<unknown file>"
        if self.episode_id is not None:
            head += f" [{self.episode_id}]"
        if self.frame is not None:
            head += f" frame {self.frame}"
        return f"{head}: {self.message}"

    def at_frame(self, frame: int | None) -> "EpisodeError":
        """This error, naming `frame` when it did not name one yet (the frame being processed)."""
        if self.frame is not None or frame is None:
            return self
        return EpisodeError(None, frame, self.message, file=self.file, episode_id=self.episode_id)

    def __reduce__(self):
        # Keep the fields across process-pool pickling (Exception's default
        # reduce would replay only the rendered message as `ref`).
        return (_rebuild_episode_error, (self.file, self.episode_id, self.frame, self.message))


def _rebuild_episode_error(file, episode_id, frame, message) -> EpisodeError:
    return EpisodeError(None, frame, message, file=file, episode_id=episode_id)


class AlreadyCommitted(HtdataError):
    """This very command already committed its version (killed before dataset.json was rewritten, now
    restored by htdata.write.newversion): nothing more to do. The CLI prints its one line and exits 0."""

    def __init__(self, root, version: int, command: str):
        super().__init__(f"version {version} of {root} already holds this change (committed by an earlier "
                         f"`{command}` that was interrupted before its last step; dataset.json now points to it): "
                         f"nothing to do")
        self.version = version


class RecordMismatch(DatasetError):
    """A record that decides served values (a calibration, an episode's fitted arrays) no longer matches
    its content id or digest: the one-line message names the file and the record (htdata.glove.calibration)."""


def in_context(exc: Exception, context: str) -> Exception | None:
    """An error of `exc`'s own type whose message starts with `context` (where it happened), for
    `raise in_context(e, where) from e`: a caller catching it by kind still does (a ConfigError stays a
    ConfigError, an OSError keeps its errno). None when the type cannot be rebuilt from one message
    (a custom constructor): re-raise `exc` itself then.
    """
    if isinstance(exc, EpisodeError):
        return EpisodeError(None, exc.frame, f"{context}: {exc.message}", file=exc.file, episode_id=exc.episode_id)
    if isinstance(exc, OSError) and exc.errno is not None:
        return type(exc)(exc.errno, f"{context}: {exc.strerror}", *([exc.filename] if exc.filename else []))
    try:
        return type(exc)(f"{context}: {exc}")
    except Exception:   # a constructor that takes other arguments
        return None
