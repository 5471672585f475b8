"""kill -9 at named points of rm, trim, gc and merge: committed versions survive, a re-run equals a clean run."""

import json
import os
import shutil
import subprocess
import sys

import pytest

from htdata.faults import ENV
from htdata.read.reader import DatasetReader
from htdata.store.versions import list_versions
from tests.factories import write_synthetic_dataset

EPISODES = [
    {"episode_id": f"ep_{i}", "task": "pour" if i % 2 else "wipe", "scene": "lab", "hands": ("right",),
     "num_frames": 3 + i}
    for i in range(5)
]
TIME_FIELDS = ("created",)


def versioned(root, episodes=EPISODES):
    return write_synthetic_dataset(root, episodes)


def htdata(args, crash_at=None):
    env = {k: v for k, v in os.environ.items() if k != ENV}
    if crash_at:
        env[ENV] = crash_at
    return subprocess.run([sys.executable, "-m", "htdata.cli", *map(str, args)], env=env,
                          capture_output=True, text=True)


def state(root):
    """Everything a reader can see, minus wall-clock times."""
    out = {"versions": list_versions(root),
           "shards": sorted(p.name for p in (root / "shards").glob("*.tar"))}
    for v in [None] + out["versions"]:
        reader = DatasetReader(root, version=v)
        manifest = {k: val for k, val in reader.manifest.items() if k not in TIME_FIELDS}
        manifest["change"] = {k: val for k, val in manifest.get("change", {}).items() if k != "time"}
        out[f"v{v}"] = {"manifest": manifest, "episodes": reader.episodes,
                        "samples": [reader.sample(i) for i in range(len(reader))]}
    return out


def same(s: dict) -> dict:
    """`state` without what names the dataset's folder or the clock: the command line (split records its
    path) and the split files' digests (a split file records when it was made)."""
    for key, value in s.items():
        if key.startswith("v") and isinstance(value, dict):
            value["manifest"]["change"].pop("command", None)
            for entry in value["manifest"].get("splits", {}).values():
                entry.pop("sha256", None)
    return s


CASES = [
    (["rm", "{ds}", "ep_1"], "repack_sample_written"),
    (["rm", "{ds}", "ep_1"], "version_files_written"),
    (["rm", "{ds}", "ep_1"], "version_manifest_written"),
    (["trim", "{ds}", "ep_4", "--frames", "1:5"], "repack_sample_written"),
    (["trim", "{ds}", "ep_4", "--frames", "1:5"], "version_manifest_written"),
    (["split", "{ds}", "--ood-task", "wipe", "--name", "main", "--seed", "1"], "version_manifest_written"),
    (["gc", "{ds}", "--keep-versions", "1", "--retention", "0", "--force"], "gc_version_deleted"),
    (["gc", "{ds}", "--keep-versions", "1", "--retention", "0", "--force"], "gc_version_files_deleted"),
]


@pytest.mark.parametrize("args,point", CASES, ids=[f"{a[0]}-{p}" for a, p in CASES])
def test_kill_then_rerun_equals_clean_run(tmp_path, args, point):
    base = versioned(tmp_path / "base")
    if args[0] == "gc":   # something to collect: a second version
        assert htdata(["rm", base, "ep_0"]).returncode == 0
    clean, crashed = tmp_path / "clean", tmp_path / "crashed"
    shutil.copytree(base, clean)
    shutil.copytree(base, crashed)
    before = state(crashed)
    fill = lambda ds: [a.format(ds=ds) for a in args]   # noqa: E731
    assert htdata(fill(clean)).returncode == 0
    killed = htdata(fill(crashed), crash_at=point)
    assert killed.returncode == 137, killed.stderr
    if point == "version_manifest_written":
        # the version file is the commit (dataset.json is its cache): the command's version is current,
        # and running the same command again finishes the job: the pointer restored, rc 0, one line
        assert same(state(crashed)) == same(state(clean))
        rerun = htdata(fill(crashed))
        assert rerun.returncode == 0 and "already holds this change" in rerun.stdout, rerun.stdout + rerun.stderr
        assert (crashed / "dataset.json").read_bytes() == (crashed / "versions" / "v000002.json").read_bytes()
        assert htdata(["validate", crashed]).returncode == 0
        assert same(state(crashed)) == same(state(clean))
        return
    # the dataset as readers see it is the one before the command (gc may have dropped old versions already)
    after_kill = state(crashed)
    assert after_kill["vNone"] == before["vNone"]
    for v in after_kill["versions"]:
        assert after_kill[f"v{v}"] == before[f"v{v}"]
    rerun = htdata(fill(crashed))
    assert rerun.returncode == 0, rerun.stderr
    assert state(crashed) == state(clean)


def test_killed_merge_reruns_to_the_clean_result(tmp_path):
    a = versioned(tmp_path / "a", EPISODES[:3])
    b = versioned(tmp_path / "b", EPISODES[2:])
    assert htdata(["merge", a, b, tmp_path / "clean"]).returncode == 0
    for point in ("merge_shards_placed", "repack_sample_written", "version_files_written"):
        out = tmp_path / f"crashed_{point}"
        assert htdata(["merge", a, b, out], crash_at=point).returncode == 137
        assert not (out / "dataset.json").exists()
        rerun = htdata(["merge", a, b, out])
        assert rerun.returncode == 0, rerun.stderr
        got, want = state(out), state(tmp_path / "clean")
        for s in (got, want):   # the command line names the output directory
            for v in ("vNone", "v1"):
                s[v]["manifest"]["change"].pop("command")
        assert got == want


def test_second_writer_is_refused_while_first_holds_the_lock(tmp_path):
    ds = versioned(tmp_path / "ds")
    code = ("import sys,time; from htdata.store.lock import WriterLock; "
            "WriterLock(sys.argv[1],'htdata ingest (test)').acquire(); print('held', flush=True); time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code, str(ds)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        res = htdata(["rm", ds, "ep_1"])
        assert res.returncode == 2 and f"pid {holder.pid}" in res.stderr and "htdata ingest (test)" in res.stderr
    finally:
        holder.kill()
        holder.wait()
    assert list_versions(ds) == [1]
    assert json.loads((ds / "dataset.json").read_text())["version"] == 1
