"""Finding a source's episodes: per-file discovery with every failure kept, stable episode ids
(`sanitise_id`, `natural_key` order) and source fingerprints (what a resumed ingest compares).

`FileDiscovery.discover_all` (base.py) runs `discover_all` here; every file it reads passes the
source-tree rules of sourcetree.py first.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Iterable

from htdata.errors import EpisodeError
from htdata.source.adapters.sourcetree import check_source_file


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
    for path in sorted(Path(p) for p in files):
        check_source_file(path, root, folders)   # every file an episode reads passes the source-tree rules
        st = path.stat()
        try:
            rel = path.relative_to(root).as_posix()
        except ValueError:
            rel = path.as_posix()
        h.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()
