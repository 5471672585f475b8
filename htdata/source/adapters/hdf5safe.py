"""HDF5 a stranger wrote, opened safely: declared sizes checked before reading, no byte read from another file.

`check_hdf5_size` refuses a dataset whose shape needs more bytes than its
storage can hold (a forged shape is an error, not a multi-GB allocation);
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


def check_hdf5_size(ref: EpisodeRef, ds, path: Path) -> None:
    """Refuse a dataset whose declared shape needs more bytes than its storage can hold (before reading it).

    Contiguous data must be fully stored; chunked (filtered) data may expand
    at most MAX_FILTER_RATIO times its stored bytes. A shape forged to 2e8
    rows is an error here instead of a multi-GB allocation on read.
    """
    need = int(np.prod(ds.shape, dtype=np.float64)) * ds.dtype.itemsize if ds.shape else ds.dtype.itemsize
    stored = int(ds.id.get_storage_size())
    limit = stored if ds.chunks is None else stored * MAX_FILTER_RATIO + (1 << 20)
    if need > limit:
        raise EpisodeError(ref, None, f"{ds.name}: declared shape {ds.shape} {ds.dtype} needs {need} bytes but the "
                           f"file stores {stored} bytes for it: refused before reading", file=path)


def in_file(ref: EpisodeRef, f, name: str, path: Path):
    """The HDF5 object `name` of `f`, refused (one line naming it) when it reads bytes of another file.

    A stranger's scene file may hold an ExternalLink (on the way to the dataset or as it), a dataset
    stored in external raw files, or a virtual dataset mapping another file: each would ingest bytes
    from outside the source folder that `source_sha256` never hashed, so none is followed.
    """
    import h5py

    node, parts = f, [p for p in name.split("/") if p]
    for part in parts:
        where = f"{node.name.rstrip('/')}/{part}"
        link = node.get(part, getlink=True)
        if isinstance(link, h5py.ExternalLink):
            raise EpisodeError(ref, None, f"{where}: an HDF5 external link to {link.filename}:{link.path}: refused "
                               f"(an episode reads only its own file)", file=path)
        node = node[part]
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
