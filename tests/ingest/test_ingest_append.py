"""Ingest into an existing dataset: append by default, nothing committed is ever lost."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from htdata.read.reader import DatasetReader
from htdata.store.versions import list_versions
from htdata.synthetic.formats import write_opentouch_annotations, write_opentouch_scene
from tests.factories import (
    COLOURS,
    ingest_cli,
    make_native,
    make_opentouch,
    make_touchanything,
    ot_clip,
    small_pipeline,
    temp_leftovers,
)


def report(out: Path) -> dict:
    return json.loads((out / "reports" / "ingest.json").read_text())


def samples(out: Path, version=None) -> dict[str, dict[str, bytes]]:
    reader = DatasetReader(out, version=version)
    return {reader.key(i): reader.sample(i) for i in range(len(reader))}


def shard_names(out: Path, version=None) -> list[str]:
    return [s["name"] for s in DatasetReader(out, version=version).manifest["shards"]]


@pytest.fixture
def ingested(tmp_path):
    """An OpenTouch raw folder, its small pipeline and a dataset ingested from it (version 1)."""
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    return raw, pipe, out


def test_second_source_is_appended_not_replacing_the_first(tmp_path):
    ot, nat = make_opentouch(tmp_path / "ot"), make_native(tmp_path / "nat")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), ot, out) == 0
    first = samples(out)
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), nat, out) == 0
    now = samples(out)
    assert {k: v for k, v in now.items() if k in first} == first and len(now) == len(first) + 9
    assert list_versions(out) == [1, 2] and samples(out, version=1) == first
    manifest = DatasetReader(out).manifest
    assert [s["name"] for s in manifest["sources"]] == ["opentouch", "native"]
    assert manifest["change"]["summary"]["episodes_added"] == 1


def test_appending_one_episode_touches_only_that_episode(ingested, tmp_path):
    raw, pipe, out = ingested
    before = {p.name: p.stat().st_mtime_ns for p in (out / "shards").glob("*.tar")}
    write_opentouch_scene(raw / "a_first_scene.hdf5", [ot_clip("demo_01", 5, COLOURS[3])])   # sorts first
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    r = report(out)
    assert r["units"] == r["units_run"] == 1 and r["episodes_unchanged"] == 3 and r["samples"] == 5
    after = {p.name: p.stat().st_mtime_ns for p in (out / "shards").glob("*.tar")}
    assert {k: v for k, v in after.items() if k in before} == before      # no shard rewritten or renamed
    assert set(shard_names(out)) - set(shard_names(out, 1)) == {"shard-000003-000.tar"}


def test_edited_labels_update_records_without_re_ingesting(ingested, tmp_path):
    raw, pipe, out = ingested
    first = samples(out)
    csv = raw / "annotations.csv"
    csv.write_text(csv.read_text().replace(",cut", ",slice"))
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    r = report(out)
    assert r["units"] == 0 and r["episodes_relabelled"] == ["ot-home_kitchen_p1-demo_02"]
    reader = DatasetReader(out)
    assert reader.episodes[reader.episode_position("ot-home_kitchen_p1-demo_02")]["task"] == "slice"
    assert "slice" in reader.manifest["tasks"] and samples(out) == first and shard_names(out) == shard_names(out, 1)
    old = DatasetReader(out, version=1)
    assert old.episodes[old.episode_position("ot-home_kitchen_p1-demo_02")]["task"] == "cut"


def test_changed_source_replaces_the_episode_and_keeps_the_old_version(ingested, tmp_path):
    raw, pipe, out = ingested
    first = samples(out)
    clips = [ot_clip("demo_01", 12, COLOURS[0]), ot_clip("demo_02", 4, COLOURS[2]), ot_clip("demo_003", 20, COLOURS[2])]
    write_opentouch_scene(raw / "home_kitchen_p1.hdf5", clips)        # re-recorded: every clip's file changed
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    r = report(out)
    assert r["episodes_replaced"] == sorted(["ot-home_kitchen_p1-demo_01", "ot-home_kitchen_p1-demo_02",
                                             "ot-home_kitchen_p1-demo_003"])
    assert DatasetReader(out).episode_range("ot-home_kitchen_p1-demo_02")[1] == 4
    assert samples(out, version=1) == first


def test_unavailable_source_keeps_its_episodes_and_says_so(ingested, tmp_path, capsys):
    raw, pipe, out = ingested
    first = samples(out)
    data = (raw / "home_kitchen_p1.hdf5").read_bytes()
    (raw / "home_kitchen_p1.hdf5").write_bytes(data[:len(data) // 2])     # the source became unreadable
    assert ingest_cli("--pipeline", pipe, raw, out) == 1                   # the file is a failure ...
    err = capsys.readouterr().err
    assert samples(out) == first                                           # ... its episodes are kept
    assert "source unavailable: ot-home_kitchen_p1-demo_01 kept from version 1" in err
    assert len(report(out)["episodes_kept_unavailable"]) == 3
    (raw / "annotations.csv").unlink()
    (raw / "home_kitchen_p1.hdf5").unlink()
    shutil.rmtree(raw)
    assert ingest_cli("--pipeline", pipe, tmp_path / "raw_gone", out) == 2   # source-wide error: exit 2 ...
    assert samples(out) == first and (out / "dataset.json").is_file()        # ... and nothing lost


def test_failed_first_run_does_not_block_the_corrected_run(tmp_path, capsys):
    raw = tmp_path / "raw"
    write_opentouch_scene(raw / "s.hdf5", [ot_clip("demo_01", 4, COLOURS[0])])
    data = (raw / "s.hdf5").read_bytes()
    (raw / "s.hdf5").write_bytes(data[:len(data) // 2])
    write_opentouch_annotations(raw / "annotations.csv", [{"id": "s::demo_01", "action": "pour"}])
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 2
    write_opentouch_scene(raw / "s.hdf5", [ot_clip("demo_01", 4, COLOURS[0])])
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, out) == 0   # other settings: fine
    assert len(samples(out)) == 4 and list_versions(out) == [1]


def test_second_writer_is_refused_with_the_holder_named(tmp_path, capsys):
    raw = make_native(tmp_path / "raw")
    out = tmp_path / "ds"
    out.mkdir()
    code = ("import sys,time; from htdata.store.lock import WriterLock; "
            "WriterLock(sys.argv[1],'htdata ingest (other run)').acquire(); print('held', flush=True); time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert ingest_cli("--pipeline", "native", raw, out) == 2
        err = capsys.readouterr().err
        assert f"pid {holder.pid}" in err and "htdata ingest (other run)" in err
    finally:
        holder.kill()
        holder.wait()
    assert ingest_cli("--pipeline", "native", raw, out) == 0     # the dead holder's lock is stale


def test_split_after_append_keeps_parts_and_assigns_new_episodes(ingested, tmp_path):
    from htdata.curate.split import write_split

    raw, pipe, out = ingested
    first = write_split(out, ["wipe"], name="main", seed=0)
    write_opentouch_scene(raw / "z.hdf5", [ot_clip("demo_01", 5, COLOURS[3])])
    with open(raw / "annotations.csv", "a") as f:
        f.write("z::demo_01,pour,,,,\n")
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    carried = DatasetReader(out).split("main")
    assert carried["carried"]["unassigned"] == ["ot-z-demo_01"]
    again = write_split(out, ["wipe"], name="main", seed=0)
    assert [e for p in again.gained.values() for e in p] == ["ot-z-demo_01"] and not any(again.lost.values())
    for part, ids in first.doc["parts"].items():
        assert set(ids["episodes"]) <= set(again.doc["parts"][part]["episodes"])


def test_pool_workers_die_when_the_main_process_is_killed(tmp_path, spawn):
    raw = make_opentouch(tmp_path / "raw")
    out = tmp_path / "ds"
    cmd = [sys.executable, "-m", "htdata.cli", "ingest", "--workers", "2", "--quiet", "--pipeline",
           str(small_pipeline(tmp_path, "opentouch")), str(raw), str(out)]
    # own process group, killed by the fixture whatever happens below (a failed assert must not leave a
    # hung ingest behind); the bounds are generous: they only end a test that is already broken
    proc = spawn(cmd, env={**os.environ, "HTDATA_TEST_FAULT_UNIT": "0", "HTDATA_TEST_FAULT": "hang"},
                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while not list((out / "shards").glob("*shard-000000-*")):
        assert proc.poll() is None and time.time() < deadline, "ingest ended before it could be killed"
        time.sleep(0.05)
    workers = [p for p in psutil.Process(proc.pid).children(recursive=True)
               if "htdata" in " ".join(p.cmdline()) or "multiprocessing" in " ".join(p.cmdline())]
    assert workers
    os.kill(proc.pid, signal.SIGKILL)          # the main process alone, not its group
    proc.wait(timeout=30)
    gone, alive = psutil.wait_procs(workers, timeout=120)   # returns as soon as they are gone (PDEATHSIG)
    assert not alive, [p.cmdline() for p in alive]
    assert not (out / "dataset.json").exists()
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, out) == 0
    assert temp_leftovers(out) == []


def test_touchanything_append_after_native(tmp_path):
    """Two formats, two runs, one dataset; the second run's report counts the first as unchanged-elsewhere."""
    nat, ta = make_native(tmp_path / "nat"), make_touchanything(tmp_path / "ta")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), nat, out) == 0
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "touchanything"), ta, out) == 0
    reader = DatasetReader(out)
    assert {e["source"] for e in reader.episodes} == {"native", "touchanything"}
    assert reader.manifest["counts"]["frames_per_hand"]["left"] == 11
    assert np.isfinite(reader.decoded(0)["tactile"]["right"]).all()


@pytest.mark.parametrize("n_chars", [80, 180])
def test_long_episode_ids_ingest(tmp_path, n_chars):
    from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording

    raw = tmp_path / "raw"
    t = np.arange(6, dtype=np.int64) * 33_333_333
    rec = NativeRecording(task="grasp", scene="lab", video_storage="jpeg",
                          video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * 6, video_timestamps_ns=t,
                          hands={"right": NativeHand("opentouch_right_16x16",
                                                     np.full((6, 16, 16), 1536.0, np.float32), t)})
    name = "r" * n_chars
    write_native_recording(raw / name, rec)
    write_native_recording(raw / "short", rec)
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, out) == 0
    reader = DatasetReader(out)
    ids = [e["episode_id"] for e in reader.episodes]
    assert any(len(i) > n_chars for i in ids) and len(reader) == 12
    long_id = max(ids, key=len)
    assert reader.decoded(reader.episode_range(long_id)[0])["meta"]["episode_id"] == long_id
