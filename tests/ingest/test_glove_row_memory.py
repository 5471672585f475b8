"""Issue 35 item 8: glove-row memory capped while reading.

~95 bytes per input row were held before the per-sample row cap applied (a 54 MB npz of 21M deflated rows
took 2.0 GB). Now a stream may declare at most MAX_STREAM_ROWS rows (refused from its header, before a
timestamp is read), and planning holds a few bytes per row: the pairing takes no per-row copy of an
increasing stream, and the row plan is built a block of rows at a time, each block capped per sample.
"""

from __future__ import annotations

import numpy as np

from htdata.ingest import fullrate
from htdata.source import sync
from htdata.source.adapters import streamchecks
from tests.factories import FRAME_NS, ingest_cli, make_native
from tests.factories.hostile import peak_rss_mb, write_long_glove


def test_a_stream_declaring_more_rows_than_an_episode_may_hold_is_refused_by_its_header(tmp_path, monkeypatch,
                                                                                       capsys):
    monkeypatch.setattr(streamchecks, "MAX_STREAM_ROWS", 50_000)
    raw = make_native(tmp_path / "raw")
    npz = raw / "rec_good" / "tactile_right.npz"
    write_long_glove(npz, 50_001, 0, 1000)
    assert ingest_cli("--pipeline", "native", raw, tmp_path / "ds") == 2
    err = capsys.readouterr().err
    assert (f"{npz} [nat-rec_good]: right tactile stream declares 50001 rows, more than one episode's stream may "
            f"hold (50000, 0 min at 2 kHz): refused before reading") in err, err


def test_planning_a_long_packed_glove_stream_holds_a_few_bytes_per_row(tmp_path):
    """1.5M rows packed beside 9 frames (a 3.5 MB npz): the ingest's peak grows by ~45 MB over a warm run
    (it grew by ~150 MB, ~100 bytes a row); the rows over the per-sample cap are counted as before."""
    rows = 1_500_000
    big = make_native(tmp_path / "big")
    write_long_glove(big / "rec_good" / "tactile_right.npz", rows, 0, (9 * FRAME_NS) // rows)
    make_native(tmp_path / "small")
    code = f"""
import contextlib, io
from htdata.benchmarks.ingest import own_peak_rss_kb
from tests.factories import ingest_cli
with contextlib.redirect_stderr(io.StringIO()) as err:
    assert ingest_cli("--pipeline", "native", {str(tmp_path / 'small')!r}, {str(tmp_path / 'ds0')!r}) == 0
    warm = own_peak_rss_kb()
    rc = ingest_cli("--pipeline", "native", {str(big)!r}, {str(tmp_path / 'ds1')!r})
print("rc", rc, "warm_kb", warm)
print(err.getvalue())
"""
    out, peak = peak_rss_mb(code)
    warm = int(out.split("warm_kb ")[1].split()[0]) / 1024
    assert "rc 0" in out and "glove rows dropped over the 4016 rows one sample may store" in out, out
    assert peak - warm < 100, (warm, peak)


def test_row_plans_built_block_by_block_equal_one_block(monkeypatch):
    """The block-wise plan (each block capped per slot first) keeps exactly the rows, slots and counts of a
    plan over every row at once: unsorted, duplicated, packed and spread stamps, with and without frames."""
    rng = np.random.default_rng(7)
    for trial in range(150):
        m, f = int(rng.integers(1, 2500)), int(rng.integers(0, 12))
        ts = [np.sort(rng.integers(0, 5 * 10**9, m)), np.cumsum(rng.integers(1, 10**7, m)),
              rng.integers(0, 3 * 10**9, m), 10**9 + rng.integers(0, 3, m) * 100][trial % 4].astype(np.int64)
        frames = np.unique(rng.integers(0, 4 * 10**9, f)).astype(np.int64)
        paired = rng.choice(m, size=min(m, frames.size), replace=False)
        plans = []
        for block in (7, 1 << 18):
            monkeypatch.setattr(fullrate, "_BLOCK", block)
            monkeypatch.setattr(sync, "_BLOCK", block)
            plans.append(fullrate.RowPlan.build(ts, paired, frames))
        a, b = plans
        assert np.array_equal(a.rows, b.rows) and np.array_equal(a.slots, b.slots), trial
        assert (a.dropped, a.capped, a.cap) == (b.dropped, b.capped, b.cap), trial
