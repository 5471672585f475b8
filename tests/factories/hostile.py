"""Hostile inputs the tests share, and a peak-memory probe.

`forged_jpeg(width, height)`: a real few-hundred-byte JPEG whose frame header declares another size (a
decoder would allocate width x height x 3 bytes before finding the data missing).
`forged_exr(data_window, display_window)`: a small EXR whose header declares the given windows.
`peak_rss_mb(code)`: run `code` in a fresh interpreter (this checkout on its path) and return
(its stdout, its peak RSS in MB): memory-sensitive cases run there, so a regression costs that process,
not the test runner, and the number is the process's own.
`read_members` / `rewrite_members`: a sample's member bytes read from its shard / replaced by hand, the
index and manifest re-sealed, so that only content checks can notice.
`write_long_glove`: a native glove npz of millions of constant rows, written block by block.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import OpenEXR

ROOT = Path(__file__).resolve().parents[2]

# the child's own peak: VmHWM (exec resets it); ru_maxrss would carry the forking pytest worker's across exec
# (htdata.benchmarks.ingest.own_peak_rss_kb reads it the same way)
_PEAK = ("\nimport sys as _s\n_hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]\n"
         "_s.stdout.write('\\nPEAK_RSS_KB %d\\n' % int(_hwm.split()[1]))\n")


def forged_jpeg(width: int, height: int) -> bytes:
    """An 8x8 JPEG with its SOF0 size patched to `width` x `height`."""
    ok, buf = cv2.imencode(".jpg", np.full((8, 8, 3), 128, np.uint8))
    assert ok
    data = bytearray(buf.tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5:sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data)


def forged_exr(data_window: tuple, display_window: tuple) -> bytes:
    """A 1x1 half EXR whose header declares `data_window` / `display_window` ((x0, y0), (x1, y1)) instead."""
    buf = io.BytesIO()
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
                  "dataWindow": ((0, 0), (0, 0)), "displayWindow": ((0, 0), (0, 0))},
                 {"Y": np.zeros((1, 1), np.float16)}).write(buf)
    data = bytearray(buf.getvalue())
    for name, (a, b) in (("dataWindow", data_window), ("displayWindow", display_window)):
        at = data.find(name.encode() + b"\0box2i\0") + len(name) + len("\0box2i\0") + 4
        data[at:at + 16] = np.array([*a, *b], "<i4").tobytes()
    return bytes(data)


def peak_rss_mb(code: str, timeout: float = 300) -> tuple[str, float]:
    """(stdout, peak RSS in MB) of `code` run by this interpreter in a subprocess; raises when it fails."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    done = subprocess.run([sys.executable, "-c", code + _PEAK], capture_output=True, text=True, env=env,
                          timeout=timeout, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    out, _, tail = done.stdout.rpartition("\nPEAK_RSS_KB ")
    return out, int(tail.split()[0]) / 1024


# --------------------------------------------------------------------------- members rewritten by hand

def _manifest(root: Path) -> dict:
    import json

    from htdata.format.table import MANIFEST_FILE

    return json.loads((Path(root) / MANIFEST_FILE).read_text())


def read_members(root: Path, row: int) -> dict[str, bytes]:
    """The members of index row `row` of the current version, read straight from its shard."""
    from htdata.format.shardio import BLOCK, padded
    from htdata.format.table import SHARDS_DIR, SIZE_FIELDS
    from htdata.store.manifest import load_index, load_records

    stored = _manifest(root)
    manifest, _ = load_records(root, stored)
    r = load_index(root, mmap=False, manifest=stored)[row]
    out = {}
    with open(Path(root) / SHARDS_DIR / manifest["shards"][int(r["shard"])]["name"], "rb") as f:
        header = int(r["offset"])
        for suffix, col in SIZE_FIELDS.items():
            size = int(r[col])
            if size:
                f.seek(header + BLOCK)
                out[suffix] = f.read(size)
                header += BLOCK + padded(size)
    return out


def rewrite_members(root: Path, row: int, replacement: dict[str, bytes]) -> None:
    """Replace member bytes of one sample, bypassing every writer check, then fix the shard's offsets/sizes in
    the version's index.npy and the sha256/bytes in its manifest (both copies) so that only the content
    checks can notice."""
    import hashlib

    from htdata.format.shardio import BLOCK, member_header, padded
    from htdata.format.table import SHARDS_DIR, SIZE_FIELDS
    from htdata.store.manifest import load_episodes, load_index
    from tests.factories import rewrite_manifest
    from tests.factories.legacy import as_format3

    root = Path(root)
    if "segments" in _manifest(root):
        as_format3(root)     # the edit re-seals a version's own index.npy: the format 3 records (legacy.py)
    manifest = _manifest(root)
    index = load_index(root, mmap=False, manifest=manifest).copy()
    shard_pos = int(index[row]["shard"])
    entry = manifest["shards"][shard_pos]
    eps = [e["episode_id"] for e in load_episodes(root, manifest)]
    out = bytearray()
    for r in np.flatnonzero(index["shard"] == shard_pos):
        members = read_members(root, int(r))
        if r == row:
            members.update(replacement)
        key = f"{eps[int(index[r]['episode'])]}__{int(index[r]['frame']):06d}"
        index[r]["offset"] = len(out)
        for suffix, col in SIZE_FIELDS.items():
            data = members.get(suffix, b"")
            index[r][col] = len(data)
            if data:
                out += member_header(f"{key}.{suffix}", len(data)) + data + b"\0" * (padded(len(data)) - len(data))
    out += b"\0" * (2 * BLOCK)
    (root / SHARDS_DIR / entry["name"]).write_bytes(bytes(out))
    entry["sha256"] = hashlib.sha256(out).hexdigest()
    entry["bytes"] = len(out)
    buf = io.BytesIO()
    np.save(buf, index, allow_pickle=False)
    (root / manifest["index_file"]).write_bytes(buf.getvalue())
    manifest["index_sha256"] = hashlib.sha256(buf.getvalue()).hexdigest()
    rewrite_manifest(root, manifest)


# --------------------------------------------------------------------------- a long glove stream, deflated

def _npy_member(z, name: str, dtype, shape: tuple, blocks) -> None:
    from numpy.lib import format as npy

    with z.open(name, "w", force_zip64=True) as f:
        head = io.BytesIO()
        npy.write_array_header_1_0(head, {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": shape})
        f.write(head.getvalue())
        for block in blocks:
            f.write(block)


def write_long_glove(npz: Path, rows: int, t0: int, step_ns: int, value: int = 0, dtype="<u1") -> None:
    """A native tactile_<hand>.npz of `rows` constant 16x16 rows stamped t0, t0 + step_ns, ... written in
    blocks (never the whole array in memory): deflated, a few million rows take a few MB."""
    import zipfile

    chunk = 1 << 16
    row = np.full((16, 16), value, dtype)
    full = np.broadcast_to(row, (chunk, 16, 16)).tobytes()
    with zipfile.ZipFile(npz, "w", zipfile.ZIP_DEFLATED) as z:
        _npy_member(z, "values.npy", dtype, (rows, 16, 16),
                    (full[:min(chunk, rows - s) * row.nbytes] for s in range(0, rows, chunk)))
        _npy_member(z, "timestamps_ns.npy", "<i8", (rows,),
                    ((t0 + np.arange(s, min(s + chunk, rows), dtype=np.int64) * step_ns).tobytes()
                     for s in range(0, rows, chunk)))
