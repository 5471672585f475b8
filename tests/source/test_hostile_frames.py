"""Issue 35 item 4: a source frame's size is read from its JPEG header before it is decoded.

A 691-byte JPEG declaring 30000x30000 cost ~5.2 GB at ingest (rc 0, no note). Now a frame beyond
MAX_SOURCE_FRAME_PIXELS fails its episode with file, episode and frame named, before the decoder
allocates it (checked in a fresh process's peak RSS); the other episodes are ingested.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from htdata.source.rgb import MAX_SOURCE_FRAME_PIXELS, decode_jpeg_frame
from tests.factories import make_native, make_opentouch
from tests.factories.hostile import forged_jpeg, peak_rss_mb

INGEST = """
import contextlib, io, sys
from tests.factories import ingest_cli
err = io.StringIO()
with contextlib.redirect_stderr(err):
    rc = ingest_cli("--pipeline", {pipeline!r}, {raw!r}, {out!r})
print("rc", rc)
print(err.getvalue())
"""


def test_decode_refuses_a_header_beyond_the_limit_and_decodes_the_rest():
    with pytest.raises(ValueError, match=r"JPEG declares 30000x30000 pixels \(900 Mpx\), more than a source frame "
                                         r"may hold \(16.8 Mpx\): refused before decoding"):
        decode_jpeg_frame(forged_jpeg(30000, 30000))
    side = int(MAX_SOURCE_FRAME_PIXELS ** 0.5)
    with pytest.raises(ValueError, match="refused before decoding"):
        decode_jpeg_frame(forged_jpeg(side + 1, side))
    with pytest.raises(ValueError, match="declares 8x0 pixels"):
        decode_jpeg_frame(forged_jpeg(8, 0))
    assert decode_jpeg_frame(forged_jpeg(8, 8)).shape == (8, 8, 3)   # within the limit: decoded as before


def test_an_opentouch_frame_declaring_30000x30000_fails_its_episode_in_little_memory(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    bomb = forged_jpeg(30000, 30000)
    assert len(bomb) < 1000
    with h5py.File(raw / "home_kitchen_p1.hdf5", "r+") as f:
        f["data/demo_02/rgb_images_jpeg"][2] = np.frombuffer(bomb, np.uint8)
    out, peak = peak_rss_mb(INGEST.format(pipeline="opentouch", raw=str(raw), out=str(tmp_path / "ds")))
    assert "rc 1" in out
    assert ("home_kitchen_p1.hdf5 [ot-home_kitchen_p1-demo_02] frame 2: JPEG declares 30000x30000 pixels "
            "(900 Mpx), more than a source frame may hold") in out
    assert "ingested 2/3 episodes" in out
    assert peak < 500, peak


def test_a_native_jpeg_frame_declaring_30000x30000_fails_its_episode_naming_the_file(tmp_path):
    raw = make_native(tmp_path / "raw")
    frame = raw / "rec_good" / "frames" / "000004.jpg"
    frame.write_bytes(forged_jpeg(30000, 30000))
    out, peak = peak_rss_mb(INGEST.format(pipeline="native", raw=str(raw), out=str(tmp_path / "ds")))
    assert f"{frame} [nat-rec_good] frame 4: JPEG declares 30000x30000 pixels" in out, out
    assert peak < 500, peak
