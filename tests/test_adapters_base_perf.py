"""Per-episode costs of the shared adapter helpers: single-threaded video decode, cached layout grids."""

from __future__ import annotations

import os
import shutil

import av
import numpy as np
import pytest

from htdata.adapters import base
from htdata.adapters.base import configure_decoder_threads, iter_video_rgb, layout_grid
from htdata.sample.formats import write_h264


def _video(path, n=12):
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(n)]
    write_h264(path, iter(frames), fps=30.0)
    return path


def _default_thread_decode(path):
    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(c.streams.video[0])]


def test_single_threaded_decode_is_bit_exact(tmp_path):
    path = _video(tmp_path / "v.mp4")
    ours = list(iter_video_rgb(path))
    ref = _default_thread_decode(path)
    assert len(ours) == len(ref) == 12
    assert all(np.array_equal(a, b) for a, b in zip(ours, ref))


def test_configure_decoder_threads(tmp_path):
    path = _video(tmp_path / "v.mp4", n=2)
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        configure_decoder_threads(s)
        assert s.codec_context.thread_count == 1 and "SLICE" in str(s.thread_type)
        configure_decoder_threads(s, 2)
        assert s.codec_context.thread_count == 2


def test_layout_grid_parsed_once_per_file_version(tmp_path, monkeypatch):
    from htdata import layouts

    src = layouts.layout_path("opentouch_right_16x16")
    path = tmp_path / "my_glove.json"
    shutil.copy(src, path)
    calls = []
    real = layouts.load_layout
    monkeypatch.setattr(layouts, "load_layout", lambda p: calls.append(p) or real(p))
    base._cached_layout_grid.cache_clear()
    assert layout_grid(str(path)) == (16, 16)
    assert layout_grid(str(path)) == (16, 16)
    assert len(calls) == 1
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))   # the file changed: parsed again
    assert layout_grid(str(path)) == (16, 16) and len(calls) == 2
    assert layout_grid("opentouch_right_16x16") == (16, 16)


def test_layout_grid_missing_layout_names_it():
    with pytest.raises(FileNotFoundError, match="no_such_glove"):
        layout_grid("no_such_glove")
