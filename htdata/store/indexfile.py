"""An index .npy file read safely: its header checked against its size before anything is mapped, its
rows as INDEX_DTYPE (an older format's converted in memory).

Every index a reader opens goes through here: a format 3 version's index.npy, a format 4
segment's rows (htdata/store/segments.py), a remote index cached locally (htdata/store/remote.py).
"""

from __future__ import annotations

import io
import os

import numpy as np

from htdata.errors import DatasetError
from htdata.format.table import INDEX_DTYPE, INDEX_DTYPES
from htdata.store import storage


class IndexDtypeError(DatasetError):
    """index.npy is readable but its rows are not INDEX_DTYPE (`found`: their dtype)."""

    def __init__(self, where: str, found: np.dtype):
        super().__init__(f"{where}: index dtype {found} != {INDEX_DTYPE}")
        self.found = found


def _check_index_dtype(rows: np.ndarray, where: str) -> np.ndarray:
    """Rows as INDEX_DTYPE: an older format's index (fewer size columns) is converted in memory, sizes 0."""
    if rows.dtype == INDEX_DTYPE:
        return rows
    if rows.dtype not in INDEX_DTYPES.values():
        raise IndexDtypeError(where, rows.dtype)
    converted = np.zeros(rows.shape, dtype=INDEX_DTYPE)
    for name in rows.dtype.names:
        converted[name] = rows[name]
    return converted


def _check_index_header(f, size: int, where: str) -> None:
    """Refuse an index.npy whose header declares more rows than its bytes hold, before np.load maps or
    allocates them (a header declaring 1e11 rows was a bare mmap ValueError, or a 4 TB allocation)."""
    from numpy.lib import format as npy

    try:
        version = npy.read_magic(f)
        shape, _, dtype = (npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0)(f)
    except Exception as e:
        raise DatasetError(f"{where}: unreadable index header: {e}") from None
    rows = 1
    for d in shape:
        rows *= int(d)
    held = size - f.tell()
    if rows * dtype.itemsize > held:
        raise DatasetError(f"{where}: index header declares {rows} rows of {dtype.itemsize} bytes but the file "
                           f"holds {held} bytes of rows: damaged or forged index, refused")


def parse_index(data: bytes, where: str) -> np.ndarray:
    """index.npy bytes -> rows (for callers that hash the bytes they parse)."""
    _check_index_header(io.BytesIO(data), len(data), where)
    try:
        rows = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as e:
        raise DatasetError(f"{where}: unreadable index: {e}") from None
    return _check_index_dtype(rows, where)


def load_index_file(path: str, mmap: bool = True) -> np.ndarray:
    """An index.npy file (local path or URL) as INDEX_DTYPE; memory-mapped when local and `mmap`.

    A format 1/2 index is converted to INDEX_DTYPE in memory (not mapped); a
    new version of such a dataset writes its index in the current dtype.
    """
    local = storage.local_path(path)
    if local is None:
        return parse_index(storage.read_bytes(path), path)
    with open(local, "rb") as f:
        _check_index_header(f, os.fstat(f.fileno()).st_size, path)
    try:
        rows = np.load(local, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DatasetError(f"{path}: unreadable index: {e}") from None
    return _check_index_dtype(rows, path)
