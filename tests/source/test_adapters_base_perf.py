"""Per-episode costs of the shared adapter helpers: single-threaded, bit-exact video decode.

(Layouts parsed once per file version: tests/glove/test_layouts.py.)
"""

from __future__ import annotations

import av
import numpy as np

from htdata.source.adapters.video import configure_decoder_threads, iter_video_rgb
from htdata.synthetic.formats import write_h264


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
