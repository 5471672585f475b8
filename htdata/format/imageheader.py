"""Image sizes read from the header bytes, before a decoder allocates anything.

A 691-byte JPEG may declare 30000x30000 pixels and an 0.9 MB EXR a 20000x20000
data window: a decoder allocates what the header declares (GBs) before it
finds out the data is not there. `jpeg_size` and `exr_windows` read the
declared size from the first few hundred bytes (a few microseconds), so the
callers refuse what cannot be right before decoding: a shard member that is
not 224x224 (htdata/format/codec.py, tactilecodec.py), a source frame beyond
MAX_SOURCE_FRAME_PIXELS (htdata/source/rgb.py).
"""

from __future__ import annotations

import struct

from htdata.errors import DatasetError


class DeclaredShapeError(DatasetError):
    """A member whose header declares another shape than the format's; `found` is the declared (H, W)."""

    def __init__(self, message: str, found: tuple[int, int]):
        super().__init__(message)
        self.found = found


# JPEG start-of-frame markers (SOF0..SOF15 but DHT C4, JPG C8, DAC CC): they carry the frame size
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# markers without a length field: TEM, RST0..7 (SOI is checked first, EOI / SOS end the search)
_STANDALONE = frozenset([0x01, *range(0xD0, 0xD8)])


def jpeg_size(data: bytes | memoryview) -> tuple[int, int] | None:
    """(height, width) a JPEG's frame header declares, or None when the bytes hold no frame header
    before the scan (not a JPEG, truncated): the caller refuses it without decoding."""
    n = len(data)
    if n < 4 or data[0] != 0xFF or data[1] != 0xD8:
        return None
    i = 2
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:          # fill byte before a marker
            i += 1
            continue
        if marker in _STANDALONE:
            i += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image / start of scan: no frame header came first
            return None
        length = (data[i + 2] << 8) | data[i + 3]
        if marker in _SOF:
            if i + 9 > n or length < 8:
                return None
            height, width = struct.unpack_from(">HH", data, i + 5)
            return int(height), int(width)
        if length < 2:
            return None
        i += 2 + length
    return None


_EXR_MAGIC = b"\x76\x2f\x31\x01"
_EXR_HEADER_LIMIT = 1 << 16      # our maps' headers are ~300 bytes; attributes past this are not read


def exr_windows(data: bytes | memoryview) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]] | None:
    """(dataWindow, displayWindow) of an EXR's (first) header, each (x0, y0, x1, y1) inclusive, or None when
    the header does not parse or lacks either window."""
    head = data if isinstance(data, bytes) else bytes(data)
    if len(head) < 8 or head[:4] != _EXR_MAGIC:
        return None
    end = min(len(head), 8 + _EXR_HEADER_LIMIT)
    found: dict[str, tuple[int, int, int, int]] = {}
    i = 8
    while i < end and head[i] != 0:      # an empty name ends the header
        name_end = head.find(b"\0", i, end)
        type_end = head.find(b"\0", name_end + 1, end) if name_end >= 0 else -1
        if type_end < 0 or type_end + 5 > end:
            return None
        name = head[i:name_end]
        (size,) = struct.unpack_from("<i", head, type_end + 1)
        start = type_end + 5
        if size < 0 or start + size > end:
            return None
        if size == 16 and name in (b"dataWindow", b"displayWindow") and head[name_end + 1:type_end] == b"box2i":
            found[name.decode()] = struct.unpack_from("<4i", head, start)
        i = start + size
    if "dataWindow" not in found or "displayWindow" not in found:
        return None
    return found["dataWindow"], found["displayWindow"]


def check_exr_windows(data: bytes | memoryview, shape: tuple[int, int], where: str) -> tuple:
    """(dataWindow, displayWindow) of an EXR member, refused before its pixels are read unless the display
    window is `shape` (H, W) and holds the data window: a DatasetError (DeclaredShapeError for a wrong
    size) naming `where`, so a forged 20000x20000 window never reaches the decoder."""
    windows = exr_windows(data)
    if windows is None:
        raise DatasetError(f"{where}: undecodable EXR ({len(data)} bytes): no readable header with a data and a "
                           f"display window")
    (x0, y0, x1, y1), (dx0, dy0, dx1, dy1) = windows
    found = (dy1 - dy0 + 1, dx1 - dx0 + 1)
    if found != tuple(shape):
        raise DeclaredShapeError(f"{where}: EXR display window {(dx0, dy0, dx1, dy1)} is {found[0]}x{found[1]}, "
                                 f"expected {shape[0]}x{shape[1]}: not decoded", found)
    if not (dx0 <= x0 <= x1 <= dx1 and dy0 <= y0 <= y1 <= dy1):
        raise DatasetError(f"{where}: EXR data window {(x0, y0, x1, y1)} is not inside its display window "
                           f"{(dx0, dy0, dx1, dy1)}: not decoded")
    return windows
