"""Finding a source's episodes: per-file discovery with every failure kept, stable episode ids
(`sanitise_id`, `natural_key` order) and source fingerprints (what a resumed ingest compares).

`FileDiscovery.discover_all` (base.py) runs `discover_all` here; every file it reads passes the
source-tree rules of sourcetree.py first.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from pathlib import Path
from typing import Iterable

from htdata.errors import EpisodeError
from htdata.source.adapters.sourcetree import check_source_file, plain_path, real_path


def discovery_failure(path: Path, exc: BaseException) -> EpisodeError:
    """`exc` raised while discovering `path` as an EpisodeError naming the file (and episode when known)."""
    if isinstance(exc, EpisodeError):
        if exc.file is not None:
            return exc
        return EpisodeError(None, exc.frame, exc.message, file=path, episode_id=exc.episode_id)
    return EpisodeError(None, None, f"{type(exc).__name__}: {exc}", file=path)


def discover_all(adapter, root: Path | str, params: dict) -> tuple[list, list[EpisodeError]]:
    """(EpisodeRefs sorted naturally by episode id, one EpisodeError per file or episode that failed).

    `adapter` is a base.FileDiscovery (not imported: the contract calls this module).

    A file that raises while being read becomes a failure and every other
    file is still discovered; an episode id already produced by an earlier
    file is a failure of the later one (the first keeps the id).
    """
    root = Path(root)
    files = adapter.discovery_files(root, params)
    if not files:   # nothing of this format here: say that, not what the source-wide context lacks
        return [], []
    context = adapter.discovery_context(root, params)
    refs = []
    failures: list[EpisodeError] = []
    seen: dict[str, str] = {}
    for path in files:
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
    folders: dict = {}                  # each folder resolved once (sourcetree.real_path)
    names = [os.fspath(p) for p in files]
    fast = FastFiles(root, folders) if names and all(map(plain_path, names)) and len(
        {n.startswith("/") for n in names}) == 1 else None
    # plain paths, all absolute or all relative: split at "/" they sort as Path objects do (by parts)
    for name in (sorted(names, key=lambda n: n.split("/")) if fast else map(str, sorted(map(Path, names)))):
        st = fast.checked_stat(name) if fast else None
        if st is None:                  # the general rule, pathlib's (a symlink, a file it refuses, odd paths)
            path = Path(name)
            check_source_file(path, root, folders)   # every file an episode reads passes the source-tree rules
            st = path.stat()
        rel = name[len(fast.root) + 1:] if fast and name.startswith(fast.root + "/") else _relative(name, root)
        h.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _relative(name: str, root: Path) -> str:
    path = Path(name)
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return path.as_posix()


class FastFiles:
    """`check_source_file` + `stat` of plain paths (sourcetree.plain_path) that are no symlink, from one lstat
    and string operations: discovery fingerprints every file an episode reads, one per frame in a JPEG
    folder. Anything else (a symlink, an lstat that fails, a file outside the root or not regular) returns
    None: the caller takes the general path, which raises the same error it always did."""

    def __init__(self, root: Path, folders: dict):
        self.root = str(root)
        real = str(real_path(root, folders))
        self.inside = "/" if real == "/" else real + "/"
        self.folders: dict[str, str] = {}

    def checked_stat(self, name: str) -> os.stat_result | None:
        try:
            st = os.lstat(name)
        except OSError:
            return None
        if not stat.S_ISREG(st.st_mode):       # a symlink (its target decides) or a refused type
            return None
        head, _, base = name.rpartition("/")
        if not head:
            return None
        folder = self.folders.get(head)
        if folder is None:
            folder = self.folders[head] = str(Path(head).resolve())
        real = (folder if folder != "/" else "") + "/" + base
        return st if real.startswith(self.inside) else None
