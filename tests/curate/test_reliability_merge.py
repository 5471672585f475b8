"""Two merges into one new OUT, and merges killed at every point: OUT is never destroyed, a re-run resumes.

Before issue 18 the loser of two merges started together checked "OUT is
empty" before taking the lock, then (holding it) deleted the winner's
shards/ layouts/ versions/ as "an interrupted merge's files" (1 in 3 tries);
and a `.dataset.json.*.tmp` left by a kill at the pointer write made the
re-run fail with "not empty".
"""

import json
import os
import shutil
import subprocess
import sys

from htdata.faults import ENV
from htdata.read.reader import DatasetReader
from htdata.store.versions import list_versions
from tests.factories import write_synthetic_dataset

EPISODES = [{"episode_id": f"ep_{i}", "task": "pour" if i % 2 else "wipe", "scene": "lab", "hands": ("right",),
             "num_frames": 3 + i} for i in range(5)]
# Simultaneous starts (the interleaving itself is pinned by the next test).
# P(a 1-in-3 race never shows in N independent tries) = (2/3)^N: 12 tries -> 0.8 %, so a return of the
# bug fails this test with > 99 % probability; each try is ~1 s of two small merges.
RACE_TRIES = 12


def cmd(*args):
    return [sys.executable, "-m", "htdata.cli", *map(str, args)]


def samples(root):
    reader = DatasetReader(root)
    return {reader.key(i): reader.sample(i) for i in range(len(reader))}


def inputs(tmp_path):
    return (write_synthetic_dataset(tmp_path / "a", EPISODES[:3]),
            write_synthetic_dataset(tmp_path / "b", EPISODES[2:]))   # ep_2 in both: B's unit is re-packed


def test_two_merges_started_together_never_destroy_out(tmp_path):
    a, b = inputs(tmp_path)
    clean = tmp_path / "clean"
    assert subprocess.run(cmd("merge", a, b, clean), capture_output=True).returncode == 0
    want = samples(clean)
    for k in range(RACE_TRIES):
        out = tmp_path / f"out{k}"
        procs = [subprocess.Popen(cmd("merge", a, b, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, start_new_session=True) for _ in range(2)]
        try:
            results = [(p.wait(timeout=120), *p.communicate()) for p in procs]
        finally:
            for p in procs:
                if p.poll() is None:
                    os.killpg(p.pid, 9)
                    p.wait()
        codes = sorted(r[0] for r in results)
        assert codes == [0, 2], results                        # one merged, the other refused ...
        loser = next(r for r in results if r[0] == 2)
        assert "Traceback" not in loser[2] and ("not empty" in loser[2] or "another writer" in loser[2]), loser
        assert list_versions(out) == [1] and samples(out) == want   # ... and deleted nothing
        assert not (out / ".merge.json").exists()


def test_the_losing_interleaving_refuses_and_deletes_nothing(tmp_path, monkeypatch):
    """The 1-in-3 interleaving pinned: the loser looks at OUT, the winner runs its whole merge, then the
    loser takes the lock. Before #18 the loser had decided "empty" already and deleted the winner's files."""
    import pytest

    from htdata.curate import merge as merge_mod

    a, b = inputs(tmp_path)
    out = tmp_path / "out"
    real = merge_mod.duplicates

    def winner_runs_meanwhile(*args):
        assert subprocess.run(cmd("merge", a, b, out), capture_output=True).returncode == 0
        return real(*args)

    monkeypatch.setattr(merge_mod, "duplicates", winner_runs_meanwhile)
    with pytest.raises(merge_mod.MergeConflict, match="not empty"):
        merge_mod.merge(a, b, out, "htdata merge (loser)")
    monkeypatch.undo()
    assert list_versions(out) == [1] and len(samples(out)) == 25
    assert (out / "dataset.json").is_file() and any((out / "shards").iterdir())   # the winner's files all there


def run(a, b, out, crash_at=None):
    env = {k: v for k, v in os.environ.items() if k != ENV}
    if crash_at:
        env[ENV] = crash_at
    return subprocess.run(cmd("merge", a, b, out), env=env, capture_output=True, text=True)


def test_killed_merge_resumes_at_every_point(tmp_path):
    a, b = inputs(tmp_path)
    assert run(a, b, tmp_path / "clean").returncode == 0
    want = samples(tmp_path / "clean")
    for point in ("merge_shards_placed", "repack_sample_written", "version_files_written",
                  "version_manifest_written", "merge_committed"):
        out = tmp_path / f"crashed_{point}"
        assert run(a, b, out, crash_at=point).returncode == 137
        rerun = run(a, b, out)
        assert rerun.returncode == 0, (point, rerun.stderr)
        assert samples(out) == want and list_versions(out) == [1], point
        assert not (out / ".merge.json").exists()
        assert json.loads((out / "dataset.json").read_text())["version"] == 1


def test_pointer_temp_file_left_by_a_kill_does_not_block_the_rerun(tmp_path):
    a, b = inputs(tmp_path)
    out = tmp_path / "out"
    assert run(a, b, out, crash_at="version_files_written").returncode == 137
    (out / ".dataset.json.abc123.tmp").write_bytes(b'{"format": "htd')      # a kill inside the pointer write
    rerun = run(a, b, out)
    assert rerun.returncode == 0, rerun.stderr
    assert not list(out.glob(".*.tmp")) and list_versions(out) == [1]


def test_leftovers_of_another_merge_or_none_are_refused_untouched(tmp_path):
    a, b = inputs(tmp_path)
    out = tmp_path / "out"
    assert run(a, b, out, crash_at="merge_shards_placed").returncode == 137
    before = sorted(p.name for p in (out / "shards").iterdir())
    other = run(b, a, out)                                                   # another merge into it
    assert other.returncode == 2 and "interrupted merge of" in other.stderr
    assert sorted(p.name for p in (out / "shards").iterdir()) == before
    stray = tmp_path / "stray"
    (stray / "shards").mkdir(parents=True)
    (stray / "shards" / "mine.tar").write_bytes(b"x")
    res = run(a, b, stray)
    assert res.returncode == 2 and "not empty" in res.stderr and (stray / "shards" / "mine.tar").exists()
    shutil.rmtree(stray)
