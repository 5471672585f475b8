"""Samples encoded in threads (htdata/ingest/encodepool.py): the same bytes as inline, in frame order,
a failure named with its frame; and a whole ingest byte-identical to one encoded inline."""

from __future__ import annotations

import os
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from htdata.errors import EpisodeError
from htdata.format.table import CodecSettings, encode_sample
from htdata.ingest import encodepool
from htdata.ingest.encodepool import EncodePool
from tests.factories import ingest_cli, make_native, make_touchanything

REF = SimpleNamespace(episode_id="ep", source_ref="src/rec.npz")


def _sample(i: int) -> dict:
    rng = np.random.default_rng(i)
    m = np.zeros((224, 224), np.float32)
    m[10 * (i % 10):10 * (i % 10) + 50, 40:120] = rng.random((50, 80), dtype=np.float32)
    return {"meta": {"key": f"ep__{i:06d}", "i": i}, "rgb": rng.integers(0, 255, (224, 224, 3), np.uint8),
            "tactile": {"right": m, **({"left": m[::-1].copy()} if i % 3 else {})}, "bend": {}, "raw": {}}


@pytest.mark.parametrize("threads, depth", [(0, 1), (1, 1), (2, 3), (4, 16)])
def test_the_pool_gives_the_inline_bytes_in_frame_order(threads, depth):
    settings = CodecSettings()
    samples = [_sample(i) for i in range(25)]
    got = []
    with EncodePool(settings, REF, threads=threads, depth=depth) as pool:
        for i, s in enumerate(samples):
            got += pool.put(f"ep__{i:06d}", s, i)
            assert len(got) >= i + 1 - depth          # bounded: never more than `depth` waiting
        got += pool.drain()
    assert [k for k, _ in got] == [f"ep__{i:06d}" for i in range(25)]
    assert [m for _, m in got] == [encode_sample(s, settings, f"ep__{i:06d}") for i, s in enumerate(samples)]


def test_a_glove_only_episode_encodes_inline_and_one_with_rgb_in_threads():
    """No RGB: no thread is started (the maps' short deflate calls cost more handed to threads); the first
    sample with RGB starts them. Either way the bytes are the inline ones, in frame order."""
    settings = CodecSettings()
    glove_only = [{**_sample(i), "rgb": None} for i in range(6)]
    with EncodePool(settings, REF, threads=2, depth=2) as pool:
        got = [r for i, s in enumerate(glove_only) for r in pool.put(f"ep__{i:06d}", s, i)] + pool.drain()
        assert pool._pool is None
    assert [m for _, m in got] == [encode_sample(s, settings, f"ep__{i:06d}") for i, s in enumerate(glove_only)]
    with EncodePool(settings, REF, threads=2, depth=2) as pool:
        assert pool.put("ep__000000", _sample(0), 0) == [] and pool._pool is not None   # queued, not inline
        pool.drain()


def test_a_failed_encode_names_its_frame():
    bad = _sample(7)
    bad["tactile"]["right"][3, 4] = np.nan
    with pytest.raises(EpisodeError, match=r"rec\.npz \[ep\] frame 107: .*non-finite"):
        with EncodePool(CodecSettings(), REF, threads=2, depth=2) as pool:
            for i in range(12):
                pool.put(f"ep__{i:06d}", bad if i == 7 else _sample(i), 100 + i)
            pool.drain()


def test_an_ingest_is_byte_identical_to_one_encoded_inline(tmp_path, monkeypatch):
    sources = [("native", make_native(tmp_path / "nat")), ("touchanything", make_touchanything(tmp_path / "ta"))]
    args = [a for name, src in sources for a in ("--pipeline", f"{name}={src}")]
    monkeypatch.setenv(encodepool.THREADS_ENV, "2")     # workers inherit it (limit_threads keeps a set value)
    assert ingest_cli(*args, tmp_path / "threads") == 0

    monkeypatch.setenv(encodepool.THREADS_ENV, "0")     # inline, on the calling thread
    assert ingest_cli(*args, tmp_path / "inline") == 0
    a, b = (sorted((tmp_path / d / "shards").glob("*.tar")) for d in ("threads", "inline"))
    assert [p.name for p in a] == [p.name for p in b] and a
    assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))
    shutil.rmtree(tmp_path / "inline")


@pytest.mark.parametrize("share, want", [(1, "0"), (2, "2"), (4, "4")])
def test_a_worker_encodes_in_threads_only_when_its_share_has_a_spare_core(monkeypatch, share, want):
    """Measured: with as many workers as cores, encode threads cost ~6% (inline 0.94x the wall time)."""
    from htdata.ingest.executors import limit_threads

    monkeypatch.delenv(encodepool.THREADS_ENV, raising=False)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(var, "1")          # keep this process's own caps as they are
    limit_threads(share)
    assert os.environ[encodepool.THREADS_ENV] == want and encodepool.encode_threads() == int(want)
    monkeypatch.setenv(encodepool.THREADS_ENV, "3")   # a value the user exported is kept
    limit_threads(1)
    assert encodepool.encode_threads() == 3
