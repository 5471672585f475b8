"""Forward row reads from one .npy member of an .npz, without loading the array.

Long tactile streams (native, TouchAnything) are read a chunk of rows at a
time: memory stays flat in episode length.

Declared sizes are checked against the bytes present before anything is
allocated: a member whose header declares more data than the member holds
(or whose zip entry claims more than deflate can expand to) is refused, as
is a standalone .npy (`check_npy_file`) whose header outgrows the file. A
138 KB npz declaring 2e8 timestamps is an error, not a 1.6 GB allocation.
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np


class NpzRowError(Exception):
    """A row of an npz member could not be read (`row` is the first bad row, or None)."""

    def __init__(self, row: int | None, message: str):
        self.row = row
        super().__init__(message)


_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError)
# deflate expands at most ~1032:1; a zip entry claiming more is lying about its size
MAX_DEFLATE_RATIO = 1100


def declared_nbytes(shape: tuple[int, ...], dtype: np.dtype) -> int:
    """Bytes an array of `shape` and `dtype` occupies (Python ints: no overflow on absurd shapes)."""
    n = 1
    for d in shape:
        n *= int(d)
    return n * int(dtype.itemsize)


def check_npy_file(path: Path | str) -> tuple[tuple[int, ...], np.dtype]:
    """(shape, dtype) of a standalone .npy, refused (ValueError) when its header declares more than the file holds."""
    path = Path(path)
    with open(path, "rb") as f:
        try:
            shape, _, dtype = _read_npy_header(f)
        except NpzRowError as exc:
            raise ValueError(str(exc)) from exc
        offset = f.tell()
    present = path.stat().st_size - offset
    need = declared_nbytes(shape, dtype)
    if need > present:
        raise ValueError(f"{path.name}: header declares shape {tuple(shape)} {dtype} ({need} bytes) but the file "
                         f"holds {present} bytes of data: refused before allocating")
    return tuple(shape), dtype


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
        self._check_declared_size(tuple(shape), dtype)
        self.shape, self.dtype = tuple(shape), dtype
        self.row_shape = self.shape[1:]
        self.row_bytes = int(np.prod(self.row_shape, dtype=np.int64)) * dtype.itemsize
        self._next_row = 0

    def _check_declared_size(self, shape: tuple[int, ...], dtype: np.dtype) -> None:
        """Refuse a header that declares more bytes than the zip member holds (checked before any read)."""
        info = self._zip.getinfo(self.member)
        present = info.file_size - self._stream.tell()
        need = declared_nbytes(shape, dtype)
        if need > present:
            raise NpzRowError(None, f"{self.member}: header declares shape {shape} {dtype} ({need} bytes) but the "
                              f"member holds {present} bytes of data: refused before allocating")
        archive = self.path.stat().st_size
        max_expand = 1 if info.compress_type == zipfile.ZIP_STORED else MAX_DEFLATE_RATIO
        if info.compress_size > archive or info.file_size > info.compress_size * max_expand + 4096:
            raise NpzRowError(None, f"{self.member}: zip entry claims {info.file_size} bytes from {info.compress_size} "
                              f"compressed in a {archive}-byte archive (more than the data can expand to): "
                              f"refused before allocating")

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

    def read_all(self, limit: int | None = None) -> np.ndarray:
        """Whole member (timestamps), or its first `limit` rows, streamed in chunk_rows blocks into one array:
        peak memory is the array itself, not the 4x that index, order and gather arrays over every row would add."""
        n = self.num_rows if limit is None else min(self.num_rows, max(0, int(limit)))
        out = np.empty((n,) + self.row_shape, dtype=self.dtype)
        if self._next_row > 0:
            self._open_member()
        block = max(self.chunk_rows, (1 << 20) // max(self.row_bytes, 1))   # ~1 MB per read
        for start in range(0, n, block):
            out[start:start + block] = self._read_block(min(block, n - start))
        return out

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
            self._stream = None
        self._zip.close()
