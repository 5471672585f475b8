"""Ingest benchmark helpers: a child's own peak RSS, and a bare bound doing the ingest's unavoidable work."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from htdata.benchmarks.ingest import own_peak_rss_kb
from htdata.benchmarks.sources import bare_bound, discover
from tests.factories import make_opentouch


def test_own_peak_rss_parses_vmhwm():
    status = "Name:\tpython\nVmPeak:\t  900000 kB\nVmHWM:\t  123456 kB\nVmRSS:\t  100000 kB\n"
    assert own_peak_rss_kb(status) == 123456
    assert own_peak_rss_kb() > 1000


def test_child_peak_rss_is_not_the_parents():
    ballast = np.ones(300 * 2**20, dtype=np.uint8)     # 300 MiB resident in this (parent) process
    code = "from htdata.benchmarks.ingest import own_peak_rss_kb; print(own_peak_rss_kb())"
    child_kb = int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                  check=True).stdout)
    assert ballast.sum() == ballast.size
    assert child_kb < 250 * 1024       # ru_maxrss would report >= the parent's 300 MiB here


def test_bare_bound_times_the_ingest_stages(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    cfg, adapter, refs = discover("opentouch", raw)
    b = bare_bound(cfg, adapter, refs)
    assert b["frames"] == 39                      # the frames the ingest keeps (test_ingest reads back 39)
    assert b["open_s"] > 0 and b["rgb_decode_s"] > 0 and b["tactile_read_s"] > 0
    assert np.isclose(b["decode_s"], b["open_s"] + b["rgb_decode_s"] + b["tactile_read_s"])
    assert np.isclose(b["total_s"], b["decode_s"] + b["resize_s"] + b["jpeg_s"] + b["exr_s"])
    assert b["frames_per_s"] == b["frames"] / b["total_s"]


def test_revision_rows_run_both_trees_side_by_side(tmp_path):
    """The revision rows export a commit with git archive and ingest the same inputs under both trees."""
    from htdata.benchmarks.ingest import write_long_touchanything
    from htdata.benchmarks.revisions import checkout_root, revision_rows

    if checkout_root() is None:
        pytest.skip("not running from a git checkout")
    root = write_long_touchanything(tmp_path / "corpus" / "touchanything", 12)
    r = revision_rows(tmp_path / "work", root, tmp_path / "corpus", base="HEAD", reps=1, corpus_reps=1,
                      adapters=("touchanything",))
    assert [row["case"] for row in r["rows"]] == ["episode_600", "corpus_1w"]
    for row in r["rows"]:
        assert row["frames"] == 12 and row["base_wall_s"] > 0 and row["current_peak_rss_mb"] > 10
        assert row["runs"]["base"][0]["frames"] == row["runs"]["current"][0]["frames"]
    assert (tmp_path / "work" / "revision_base" / "htdata" / "cli.py").is_file()
    assert revision_rows(tmp_path / "w2", root, tmp_path / "corpus", base="0" * 40)["skipped"].startswith("commit")


def test_the_revision_rows_default_to_every_source_of_the_sample_corpus():
    import inspect

    from htdata.benchmarks.revisions import revision_rows
    from htdata.synthetic.corpus import FORMATS

    assert inspect.signature(revision_rows).parameters["adapters"].default == FORMATS
