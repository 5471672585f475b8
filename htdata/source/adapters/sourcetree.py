"""The source tree: which files an adapter may read, and paths a recording names inside its folder.

Rules (the same for every adapter): a source file must be a regular file
(a FIFO, socket or device would block or never end: refused with a
message); a symlink is resolved and accepted only when its target lies
inside the source root (a link to another tree could ingest someone
else's data silently). Directory symlinks: one pointing outside the root
is refused (reported, not skipped); one pointing inside leads to folders
the walk reaches anyway at their real path, so their recordings are
ingested once, under that real path (stable source_ref, no loop, no
episode found twice).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from htdata.errors import EpisodeError


def _inside(path: Path, root: Path) -> bool:
    return os.path.commonpath([str(path), str(root)]) == str(root)


def real_path(path: Path, folders: dict | None = None) -> Path:
    """`path.resolve()`; with `folders` (a dict the caller keeps) each folder is resolved once and a file
    that is no symlink costs one lstat: discovery checks every file an episode reads (a JPEG folder
    holds one per frame), and resolving each from the root up is most of the driver's planning."""
    if folders is None:
        return path.resolve()
    folder = folders.get(path.parent)
    if folder is None:
        folder = folders[path.parent] = path.parent.resolve()
    full = folder / path.name
    return full.resolve() if full.is_symlink() else full


def plain_path(text: str) -> bool:
    """`text` is a path as `str(Path(text))` writes it (no "//", "/./", trailing "/" or leading "./"), so
    string operations on it (split at "/", a prefix test) agree with pathlib's: the driver's per-file fast
    paths (a JPEG folder holds one file per frame) take only such paths, anything else goes through pathlib."""
    return (bool(text) and text != "." and "//" not in text and "/./" not in text
            and not text.endswith(("/", "/.")) and not text.startswith("./"))


def _not_a_link(path: str) -> bool:
    """`not Path(path).is_symlink()`, from one lstat (the same errors ignored, others raised)."""
    try:
        return not stat.S_ISLNK(os.lstat(path).st_mode)
    except OSError as exc:
        if exc.errno in (errno.ENOENT, errno.ENOTDIR, errno.EBADF, errno.ELOOP):
            return True
        raise


class RealPaths:
    """`real_path` of many files as strings, each file and each folder resolved once: an ingest's driver
    names every source file several times (who hashes it, its checksum list line, its record). A plain
    path (`plain_path`) is resolved with string operations and one lstat, no Path object made: the same
    string `str(real_path(Path(path)))` gives."""

    def __init__(self):
        self.files: dict[str, str] = {}
        self.folders: dict = {}
        self._folder_strs: dict[str, str] = {}

    def __call__(self, path: Path | str) -> str:
        key = str(path)
        found = self.files.get(key)
        if found is None:
            found = self.files[key] = self._resolve(key)
        return found

    def _resolve(self, key: str) -> str:
        head, _, name = key.rpartition("/")
        if not (head and plain_path(key)):
            return str(real_path(Path(key), self.folders))
        folder = self._folder_strs.get(head)
        if folder is None:
            folder = self._folder_strs[head] = str(Path(head).resolve())
        full = folder + "/" + name if folder != "/" else "/" + name
        return full if _not_a_link(full) else str(Path(full).resolve())


def check_source_file(path: Path | str, root: Path | str | None, folders: dict | None = None) -> Path:
    """Raise EpisodeError (naming `path`) unless it is a regular file whose real path is inside `root`.

    `root=None` checks only the file type (e.g. when an opened episode
    re-checks a file that discovery already placed). Returns the path.
    Never opens the file, so a FIFO cannot block here. `folders`: see `real_path`.
    """
    path = Path(path)
    try:
        st = os.stat(path)   # follows symlinks: the type of what would be read
    except OSError as exc:
        raise EpisodeError(None, None, f"source file cannot be read: {exc.strerror or exc}", file=path) from exc
    real = real_path(path, folders)
    outside = root is not None and not _inside(real, real_path(Path(root), folders) if folders is not None
                                               else Path(root).resolve())
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


def relpath_inside(folder: Path, rel: str, where: str) -> Path:
    """Resolve `rel` under `folder`, refusing paths that escape it."""
    path = (folder / rel).resolve()
    real_folder = str(folder.resolve())        # once: a recording names 3-5 files, each resolved from "/"
    if os.path.commonpath([path, real_folder]) != real_folder:
        raise ValueError(f"{where}: path {rel!r} leaves the recording folder")
    return path
