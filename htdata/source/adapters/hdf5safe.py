"""HDF5 a stranger wrote, opened safely: declared sizes checked before reading, no byte read from another file.

`check_hdf5_size` refuses a dataset whose shape needs more bytes than its
storage can hold (a forged shape is an error, not a multi-GB allocation),
and a chunk that expands beyond MAX_CHUNK_BYTES (HDF5 inflates a whole chunk
to read one row of it: a 1 GiB gzip chunk is ~1 MB on disk);
`in_file` refuses external links, external raw storage and virtual datasets
mapping other files, so every byte an episode reads is in the file that
`source_sha256` hashes (docs/RELIABILITY.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.errors import EpisodeError
from htdata.source.adapters.base import EpisodeRef

# Deflate (the usual HDF5 filter) expands at most ~1032:1.
MAX_FILTER_RATIO = 1100
# One chunk, expanded: HDF5 decompresses a chunk whole to read any row of it, so this bounds the
# memory of one read (a tactile recording's chunks are KBs to a few MB; 64 MiB is far above them).
MAX_CHUNK_BYTES = 64 << 20


def check_hdf5_size(ref: EpisodeRef, ds, path: Path) -> None:
    """Refuse a dataset whose declared shape needs more bytes than its storage can hold (before reading it).

    Contiguous data must be fully stored; chunked (filtered) data may expand
    at most MAX_FILTER_RATIO times its stored bytes, and one chunk to at most
    MAX_CHUNK_BYTES. A shape forged to 2e8 rows, or a 1 GiB chunk, is an
    error here instead of a multi-GB allocation on read.
    """
    need = int(np.prod(ds.shape, dtype=np.float64)) * ds.dtype.itemsize if ds.shape else ds.dtype.itemsize
    if ds.chunks is not None:
        chunk = int(np.prod(ds.chunks, dtype=np.float64)) * ds.dtype.itemsize
        if chunk > MAX_CHUNK_BYTES:
            raise EpisodeError(ref, None, f"{ds.name}: chunk shape {ds.chunks} {ds.dtype} expands to {chunk} bytes, "
                               f"over the {MAX_CHUNK_BYTES >> 20} MiB a chunk may hold (HDF5 inflates a whole chunk "
                               f"to read one row): refused before reading", file=path)
    stored = int(ds.id.get_storage_size())
    limit = stored if ds.chunks is None else stored * MAX_FILTER_RATIO + (1 << 20)
    if need > limit:
        raise EpisodeError(ref, None, f"{ds.name}: declared shape {ds.shape} {ds.dtype} needs {need} bytes but the "
                           f"file stores {stored} bytes for it: refused before reading", file=path)


MAX_SOFT_LINKS = 16   # soft links followed on the way to one object (HDF5's own limit is similar)


def in_file(ref: EpisodeRef, f, name: str, path: Path):
    """The HDF5 object `name` of `f`, refused (one line naming it) when it reads bytes of another file.

    Every component of the path is resolved link by link: a hard link is followed; a soft link is
    resolved from the file's root (or its group) and that path checked the same way, component by
    component, so a soft link to an external link is refused like the external link itself; a dangling
    soft link, a loop, or a link of another kind is an EpisodeError naming the link. A stranger's scene
    file may hold an ExternalLink, a dataset stored in external raw files, or a virtual dataset mapping
    another file: each would ingest bytes from outside the source folder that `source_sha256` never
    hashed, so none is followed.
    """
    import h5py

    node = _resolve(ref, f.file if name.startswith("/") else f, _parts(name), path, [])
    if isinstance(node, h5py.Dataset):
        if node.external:
            raise EpisodeError(ref, None, f"{node.name}: stored in external raw file(s) "
                               f"{sorted({str(e[0]) for e in node.external})}: refused (an episode reads only "
                               f"its own file)", file=path)
        if node.is_virtual:
            others = sorted({v.file_name for v in node.virtual_sources() if v.file_name != "."})
            if others:
                raise EpisodeError(ref, None, f"{node.name}: a virtual dataset mapping {others}: refused (an "
                                   f"episode reads only its own file)", file=path)
    return node


def _parts(name: str) -> list[str]:
    return [p for p in name.split("/") if p not in ("", ".")]


def _resolve(ref: EpisodeRef, node, parts: list[str], path: Path, hops: list[str]):
    """Walk `parts` from `node`, each link checked before it is followed (see `in_file`)."""
    import h5py

    for part in parts:
        where = f"{node.name.rstrip('/')}/{part}"
        try:
            link = node.get(part, getlink=True)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise EpisodeError(ref, None, f"{where}: unreadable HDF5 link ({exc})", file=path) from exc
        if link is None:
            raise KeyError(f"{where} not found")
        if isinstance(link, h5py.ExternalLink):
            raise EpisodeError(ref, None, f"{' -> '.join([*hops, where])}: an HDF5 external link to {link.filename}:{link.path}: refused "
                               f"(an episode reads only its own file)", file=path)
        if isinstance(link, h5py.SoftLink):
            hops = hops + [where]
            if len(hops) > MAX_SOFT_LINKS:
                raise EpisodeError(ref, None, f"{hops[0]}: more than {MAX_SOFT_LINKS} soft links on the way "
                                   f"(a loop through {link.path}?): refused", file=path)
            start = node.file if link.path.startswith("/") else node    # relative: to the link's group
            try:
                node = _resolve(ref, start, _parts(link.path), path, hops)
            except KeyError:
                raise EpisodeError(ref, None, f"{' -> '.join(hops)}: a soft link to {link.path}, which names "
                                   f"nothing in the file (dangling)", file=path) from None
            continue
        if not isinstance(link, h5py.HardLink):
            raise EpisodeError(ref, None, f"{where}: an HDF5 link of kind {type(link).__name__}: refused (an "
                               f"episode follows only hard and soft links inside its file)", file=path)
        node = node[part]
    return node
