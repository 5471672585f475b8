"""An MP4's declared sizes, read from its boxes before FFmpeg opens it.

`av.open` probes the stream: it builds an index of every sample the `stsz` box declares and
decodes a frame at the size the H.264 SPS in `avcC` declares, so a 209 KB file declaring
16000x16000, or a 30 MB one declaring 3e7 samples, costs ~0.8-1.2 GB before any check of ours
could run. `check_mp4_header` walks the boxes (moov/trak/mdia/minf/stbl) with plain reads of
their headers and refuses: a sample count beyond the file's bytes (each sample is at least one
byte), and an SPS picture beyond the source frame limit. Files that are not MP4/MOV (an `.h264`
elementary stream, an MKV) are left to FFmpeg's own `max_pixels` limit (video.py).
"""

from __future__ import annotations

import struct
from pathlib import Path

CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl"}
MAX_BOXES = 10_000            # a box tree this wide is no camera's file
# FFmpeg indexes every declared sample (tens of bytes each) at open: 4M samples is 18.5 h at 60 fps and
# ~150 MB of index; a 30 MB file declaring 3e7 one-byte samples cost ~0.4-1.2 GB before any check
MAX_VIDEO_SAMPLES = 4_000_000


class Mp4HeaderError(ValueError):
    """A declared size the file cannot honour, found before the decoder opened it."""


def check_mp4_header(path: Path | str, max_pixels: int) -> None:
    """Raise Mp4HeaderError when `path`'s boxes declare more samples than its bytes or an SPS larger than
    `max_pixels`; return silently for a sound MP4 or for a file that is not an MP4 (no `ftyp`/`moov`)."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(8)
        if len(head) < 8 or head[4:8] not in (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip"):
            return
        f.seek(0)
        _walk(f, 0, size, size, max_pixels, [0])


def _walk(f, start: int, end: int, file_size: int, max_pixels: int, seen: list[int]) -> None:
    at = start
    while at + 8 <= end:
        seen[0] += 1
        if seen[0] > MAX_BOXES:
            raise Mp4HeaderError(f"more than {MAX_BOXES} boxes: not a camera's file")
        f.seek(at)
        box_size, kind = struct.unpack(">I4s", f.read(8))
        header = 8
        if box_size == 1:
            box_size = struct.unpack(">Q", f.read(8))[0]
            header = 16
        elif box_size == 0:
            box_size = end - at
        if box_size < header or at + box_size > end:
            return    # a truncated or damaged file: FFmpeg says what it can open of it (no size is declared here)
        body, body_end = at + header, at + box_size
        if kind in CONTAINERS:
            _walk(f, body, body_end, file_size, max_pixels, seen)
        elif kind == b"stsz":
            _check_stsz(f, body, body_end, file_size)
        elif kind == b"stsd":
            _check_stsd(f, body, body_end, max_pixels)
        at = body_end


def _check_stsz(f, body: int, end: int, file_size: int) -> None:
    f.seek(body)
    data = f.read(min(12, end - body))
    if len(data) < 12:
        raise Mp4HeaderError("stsz box shorter than its header")
    _, sample_size, count = struct.unpack(">III", data)
    if count > MAX_VIDEO_SAMPLES:
        raise Mp4HeaderError(f"stsz declares {count} samples, more than a recording may hold ({MAX_VIDEO_SAMPLES}: "
                             f"FFmpeg would index them all at open): refused before opening")
    if count * max(sample_size, 1) > file_size:
        raise Mp4HeaderError(f"stsz declares {count} samples of {sample_size or 'at least 1'} bytes in a "
                             f"{file_size}-byte file: refused before opening")
    if sample_size == 0 and body + 12 + 4 * count > end:
        raise Mp4HeaderError(f"stsz declares {count} sample sizes but holds {max(0, (end - body - 12) // 4)}")


def _check_stsd(f, body: int, end: int, max_pixels: int) -> None:
    """Each avc1/avc3 sample entry's avcC: the SPS picture size."""
    f.seek(body)
    data = f.read(min(end - body, 1 << 20))          # sample descriptions are bytes to KBs
    i = 8                                             # version/flags, entry count
    while i + 8 <= len(data):
        entry_size, kind = struct.unpack(">I4s", data[i:i + 8])
        if entry_size < 8 or i + entry_size > len(data):
            return
        if kind in (b"avc1", b"avc3"):
            entry = data[i + 8:i + entry_size]
            at = entry.find(b"avcC")
            if at >= 4:
                _check_avcc(entry[at + 4:], max_pixels)
        i += entry_size


def _check_avcc(avcc: bytes, max_pixels: int) -> None:
    if len(avcc) < 8:
        return
    count = avcc[5] & 0x1F
    at = 6
    for _ in range(count):
        if at + 2 > len(avcc):
            return
        n = struct.unpack(">H", avcc[at:at + 2])[0]
        width, height = sps_picture_size(avcc[at + 2:at + 2 + n])
        if width * height > max_pixels:
            raise Mp4HeaderError(f"its H.264 SPS declares {width}x{height} pixels ({width * height / 1e6:.0f} Mpx), "
                                 f"more than a source frame may hold ({max_pixels / 1e6:.1f} Mpx): refused before "
                                 f"opening")
        at += 2 + n


class _Bits:
    def __init__(self, data: bytes):
        # emulation prevention: 00 00 03 -> 00 00
        out, zeros = bytearray(), 0
        for b in data:
            if zeros >= 2 and b == 3:
                zeros = 0
                continue
            out.append(b)
            zeros = zeros + 1 if b == 0 else 0
        self.data, self.pos = bytes(out), 0

    def u(self, n: int) -> int:
        v = 0
        for _ in range(n):
            byte = self.data[self.pos >> 3] if (self.pos >> 3) < len(self.data) else 0
            v = (v << 1) | ((byte >> (7 - (self.pos & 7))) & 1)
            self.pos += 1
        return v

    def ue(self) -> int:
        zeros = 0
        while self.u(1) == 0:
            zeros += 1
            if zeros > 31:
                raise Mp4HeaderError("H.264 SPS: an Exp-Golomb code longer than 32 bits")
        return (1 << zeros) - 1 + self.u(zeros)

    def se(self) -> int:
        k = self.ue()
        return (k + 1) // 2 if k & 1 else -(k // 2)


HIGH_PROFILES = {100, 110, 122, 244, 44, 83, 86, 118, 128, 138, 139, 134, 135}


def sps_picture_size(nal: bytes) -> tuple[int, int]:
    """(width, height) in luma samples that an H.264 SPS NAL unit declares, before cropping (the size the
    decoder allocates)."""
    r = _Bits(nal[1:])                  # the NAL header byte
    profile = r.u(8)
    r.u(16)                             # constraint flags, level
    r.ue()                              # seq_parameter_set_id
    if profile in HIGH_PROFILES:
        if r.ue() == 3:                 # chroma_format_idc
            r.u(1)
        r.ue()
        r.ue()                          # bit depths
        r.u(1)
        if r.u(1):                      # seq_scaling_matrix_present_flag
            for k in range(8):
                if r.u(1):
                    _skip_scaling_list(r, 16 if k < 6 else 64)
    r.ue()                              # log2_max_frame_num_minus4
    poc = r.ue()
    if poc == 0:
        r.ue()
    elif poc == 1:
        r.u(1)
        r.se()
        r.se()
        for _ in range(min(r.ue(), 255)):
            r.se()
    r.ue()                              # max_num_ref_frames
    r.u(1)
    width_mbs = r.ue() + 1
    height_units = r.ue() + 1
    frame_mbs_only = r.u(1)
    return width_mbs * 16, height_units * 16 * (2 - frame_mbs_only)


def _skip_scaling_list(r: _Bits, size: int) -> None:
    last = nxt = 8
    for _ in range(size):
        if nxt:
            nxt = (last + r.se() + 256) % 256
        last = nxt or last
