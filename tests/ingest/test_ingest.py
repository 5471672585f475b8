"""End-to-end ingest on tiny raw fixtures in all three source formats.

Fixtures are written with htdata.synthetic.formats (the source layouts), then
ingested through the real CLI (in-process, or in a subprocess for crash tests).
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from htdata.errors import ConfigError, DatasetError, EpisodeError
from htdata.ingest import parse_sources
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


def read_all(out: Path) -> dict[str, dict[str, bytes]]:
    from htdata.read.reader import DatasetReader

    reader = DatasetReader(out)
    samples = {}
    for i in range(len(reader)):
        s = reader.sample(i)
        samples[json.loads(s["json"])["key"]] = s
    return samples


# --------------------------------------------------------------------------- planning / CLI forms

def test_resume_with_other_worker_count_keeps_every_unit(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", pipe, raw, out, workers=0) == 0
    first = dataset_bytes(out)
    assert ingest_cli("--pipeline", pipe, raw, out, workers=2) == 0
    report = json.loads((out / "reports" / "ingest.json").read_text())
    # nothing changed: no unit at all, no new version
    assert report["units"] == 0 and report["episodes_unchanged"] == 3 and report["version"] == 1
    assert dataset_bytes(out) == first


def test_parse_sources_forms(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    s, out = parse_sources(["opentouch"], [str(a), str(tmp_path / "out")])
    assert [x.pipeline.name for x in s] == ["opentouch"] and out == (tmp_path / "out").resolve()
    s, _ = parse_sources([f"opentouch={a}", f"native={b}"], [str(tmp_path / "out")])
    assert [(x.pipeline.name, x.root) for x in s] == [("opentouch", a.resolve()), ("native", b.resolve())]
    s, _ = parse_sources(["opentouch", "native"], [str(a), str(b), "out"])
    assert [x.root for x in s] == [a.resolve(), b.resolve()]
    with pytest.raises(ValueError, match="need 2 SRC"):
        parse_sources(["opentouch", "native"], [str(a), "out"])
    with pytest.raises(ValueError, match="every --pipeline"):
        parse_sources([f"opentouch={a}", "native"], [str(b), "out"])
    with pytest.raises(ValueError, match="does not exist"):
        parse_sources(["opentouch"], [str(tmp_path / "missing"), "out"])
    with pytest.raises(ValueError, match="distinct"):
        parse_sources([f"opentouch={a}", f"opentouch={b}"], ["out"])


# --------------------------------------------------------------------------- formats

def test_opentouch_ingest_reads_back(tmp_path):
    import webdataset as wds

    from htdata.glove.layouts import load_layout
    from htdata.glove.rasterise import Rasteriser
    from htdata.read.reader import DatasetReader

    raw = make_opentouch(tmp_path / "raw")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, out) == 0
    reader = DatasetReader(out)
    assert len(reader) == 39 and reader.manifest["counts"]["episodes"] == 3
    by_id = {e["episode_id"]: e for e in reader.episodes}
    assert [e["episode_id"] for e in reader.episodes] == sorted(by_id)
    ep = by_id["ot-home_kitchen_p1-demo_01"]
    assert ep["task"] == "pour" and ep["num_frames"] == 12 and abs(ep["fps"] - 30.0) < 0.01
    assert ep["sync"]["kept"] == 12 and ep["dropped_frames"] == {}
    # the 20-frame episode is one unit spanning 3 shards of 8
    assert len(by_id["ot-home_kitchen_p1-demo_003"]["shards"]) == 3

    first, n = reader.episode_range(reader.episodes.index(ep))
    d = reader.decoded(first + 5)
    assert d["meta"]["frame_index"] == 5 and d["meta"]["hands"] == {"left": False, "right": True}
    assert np.abs(d["rgb"].astype(int) - COLOURS[0]).max() <= 3   # BGR-stored JPEG came back as RGB
    # tactile round trip: sample the stored map at the taxels == (3072 - p) / 3072
    with h5py.File(raw / "home_kitchen_p1.hdf5") as f:
        p = f["data/demo_01/right_pressure"][5]
    lay = load_layout("opentouch_right_16x16")
    taxels = Rasteriser(lay).sample(d["tactile"]["right"][None])[0]
    expected = np.clip((3072 - p) / 3072, 0, 1)
    np.testing.assert_allclose(taxels[lay.live_mask], expected[lay.live_mask], atol=1e-3)

    # webdataset reads the same samples
    urls = [str(out / "shards" / s["name"]) for s in reader.manifest["shards"]]
    keys = [s["__key__"] for s in wds.WebDataset(urls, shardshuffle=False)]
    assert keys == list(read_all(out))    # same samples, same (index) order
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert report["failures"] == [] and set(report["sync"]) == set(by_id)
    assert temp_leftovers(out) == []


def test_touchanything_ingest_both_hands_and_bend(tmp_path):
    from htdata.read.reader import DatasetReader

    raw = make_touchanything(tmp_path / "raw")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "touchanything"), raw, out) == 0
    reader = DatasetReader(out)
    assert len(reader) == 11 and reader.manifest["counts"]["frames_per_hand"] == {"left": 11, "right": 11}
    d = reader.decoded(reader.episode_range(0)[0] + 4)
    assert set(d["tactile"]) == {"left", "right"}
    assert np.abs(d["rgb"].astype(int) - COLOURS[0]).max() <= 6
    s = reader.sample(0)
    assert {"bend_left.npy", "bend_right.npy"} <= set(s)
    from io import BytesIO
    bend = np.load(BytesIO(s["bend_left.npy"]))
    assert bend.shape == (66,) and np.allclose(bend, 0.25)


def test_native_100hz_glove_30hz_video(tmp_path):
    from htdata.read.reader import DatasetReader

    raw = make_native(tmp_path / "raw")
    out = tmp_path / "ds"
    # baseline "none": the glove's constant 1536 of 3072 reads 0.5 (the raw-count default would read it as rest)
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), "--set",
                      "normalise.opentouch_right_16x16.baseline=none", raw, out) == 0
    reader = DatasetReader(out)
    assert len(reader) == 9
    meta = reader.decoded(3)["meta"]
    assert abs(meta["sync_offset_ns"]["right"]) <= 5_000_000
    assert np.allclose(reader.decoded(3)["tactile"]["right"].max(), 0.5, atol=1e-3)


# --------------------------------------------------------------------------- failures

def test_bad_episodes_are_reported_and_the_rest_ingested(tmp_path, capsys):
    from htdata.read.reader import DatasetReader

    ot = make_opentouch(tmp_path / "ot", bad=True)
    nat = make_native(tmp_path / "nat", wrong_grid=True)
    out = tmp_path / "ds"
    args = ["--pipeline", f"{small_pipeline(tmp_path, 'opentouch')}={ot}",
            "--pipeline", f"{small_pipeline(tmp_path, 'native')}={nat}", out]
    assert ingest_cli(*args) == 1
    err = capsys.readouterr().err
    report = json.loads((out / "reports" / "ingest.json").read_text())
    failed = {f["episode_id"]: f for f in report["failures"]}
    assert set(failed) == {"ot-office_desk_p2-demo_01", "ot-office_desk_p2-demo_02", "ot-office_desk_p2-demo_03",
                           "nat-rec_wrong_grid"}, failed
    jpeg = failed["ot-office_desk_p2-demo_03"]
    assert jpeg["frame"] == 4 and "JPEG" in jpeg["error"] and jpeg["file"].endswith("office_desk_p2.hdf5")
    assert "non-finite" in failed["ot-office_desk_p2-demo_01"]["error"]
    assert "8, 8" in failed["nat-rec_wrong_grid"]["error"] or "(8," in failed["nat-rec_wrong_grid"]["error"]
    assert "office_desk_p2.hdf5 [ot-office_desk_p2-demo_03] frame 4" in err
    reader = DatasetReader(out)
    ids = {e["episode_id"] for e in reader.episodes}
    assert ids == {"ot-home_kitchen_p1-demo_01", "ot-home_kitchen_p1-demo_02", "ot-home_kitchen_p1-demo_003",
                   "nat-rec_good"}, ids
    assert len(reader) == 39 + 9
    # no frame of a failed episode leaked into the shards
    assert not [k for k in read_all(out) if "office_desk" in k or "wrong_grid" in k]
    # same command with --allow-failures resumes (nothing to redo) and exits 0
    assert ingest_cli("--allow-failures", *args) == 0
    assert temp_leftovers(out) == []


def truncate_half(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_unreadable_files_at_discovery_are_failures_and_the_rest_ingested(tmp_path, capsys):
    from htdata.read.reader import DatasetReader

    ot = make_opentouch(tmp_path / "ot")
    write_opentouch_scene(ot / "broken_scene.hdf5", [ot_clip("demo_01", 6, COLOURS[3])])
    truncate_half(ot / "broken_scene.hdf5")
    ta = make_touchanything(tmp_path / "ta", truncated=True)
    out = tmp_path / "ds"
    args = ["--pipeline", f"{small_pipeline(tmp_path, 'opentouch')}={ot}",
            "--pipeline", f"{small_pipeline(tmp_path, 'touchanything')}={ta}", out]
    assert ingest_cli(*args) == 1
    err = capsys.readouterr().err
    report = json.loads((out / "reports" / "ingest.json").read_text())
    found = [f for f in report["failures"] if f["stage"] == "discovery"]
    assert len(found) == len(report["failures"]) == 2, report["failures"]
    hdf5, npz = found
    assert hdf5["file"].endswith("broken_scene.hdf5") and "HDF5 does not open" in hdf5["error"]
    assert hdf5["episode_id"] is None and hdf5["source"] == "opentouch" and hdf5["frame"] is None
    assert npz["file"].endswith("20260321_101010_001/pressure_grids.npz") and "not a readable npz" in npz["error"]
    assert npz["episode_id"] == "ta-Office-open_drawer-20260321_101010_001" and npz["source"] == "touchanything"
    assert "broken_scene.hdf5: HDF5 does not open" in err
    assert "pressure_grids.npz [ta-Office-open_drawer-20260321_101010_001]: not a readable npz" in err
    reader = DatasetReader(out)
    assert {e["episode_id"] for e in reader.episodes} == {
        "ot-home_kitchen_p1-demo_01", "ot-home_kitchen_p1-demo_02", "ot-home_kitchen_p1-demo_003",
        "ta-Home-plug_usb-20260320_135743_682"}
    assert len(reader) == 39 + 5
    # a re-run resumes every unit, still reports the bad files, and --allow-failures makes it exit 0
    assert ingest_cli("--allow-failures", *args) == 0
    again = json.loads((out / "reports" / "ingest.json").read_text())
    assert again["failures"] == report["failures"] and again["units_run"] == 0
    assert temp_leftovers(out) == []


def test_source_with_only_unreadable_files_is_refused(tmp_path, capsys):
    raw = tmp_path / "raw"
    write_opentouch_scene(raw / "s.hdf5", [ot_clip("demo_01", 4, COLOURS[0])])
    truncate_half(raw / "s.hdf5")
    write_opentouch_annotations(raw / "annotations.csv", [{"id": "s::demo_01", "action": "pour"}])
    assert ingest_cli("--pipeline", "opentouch", raw, tmp_path / "ds") == 2
    assert "no episode could be ingested (1 failures)" in capsys.readouterr().err
    report = json.loads((tmp_path / "ds" / "reports" / "ingest.json").read_text())
    assert report["failures"][0]["file"].endswith("s.hdf5")
    assert not (tmp_path / "ds" / "dataset.json").exists()


def test_source_wide_discovery_error_aborts(tmp_path, capsys):
    raw = make_touchanything(tmp_path / "raw")
    (raw / "split.json").write_text("{not json")
    assert ingest_cli("--pipeline", "touchanything", raw, tmp_path / "ds") == 2
    err = capsys.readouterr().err
    assert "discovery with adapter 'touchanything' failed" in err and "split.json: not valid JSON" in err


@pytest.mark.parametrize("error", [ConfigError("adapter.params.annotations: no such column 'task'"),
                                   DatasetError("labels.csv: row 3 names no recording"),
                                   PermissionError(13, "Permission denied", "labels.csv"),
                                   EpisodeError(None, None, "split table unreadable", file="split.json")])
def test_a_source_wide_discovery_error_keeps_its_type_and_says_where(tmp_path, monkeypatch, capsys, error):
    """ingest.plan.discover_sources once re-typed every one as ValueError: a caller catching a ConfigError by
    kind missed it. Now the type stays, the message leads with the source and the adapter, the CLI one line."""
    from htdata.ingest import plan
    from htdata.ingest.pipeline import load_pipeline
    from htdata.ingest.plan import Source, discover_sources

    raw = make_native(tmp_path / "raw")
    real = plan.get_adapter

    def failing(name):
        adapter = real(name)
        monkeypatch.setattr(adapter, "discover_all", lambda root, params: (_ for _ in ()).throw(error))
        return adapter

    monkeypatch.setattr(plan, "get_adapter", failing)
    with pytest.raises(type(error), match="discovery with adapter 'native' failed") as caught:
        discover_sources([Source(load_pipeline("native"), raw)])
    assert type(caught.value) is type(error) and str(raw) in str(caught.value)
    if isinstance(error, OSError):
        assert caught.value.errno == 13 and caught.value.filename == "labels.csv"
    assert ingest_cli("--pipeline", "native", raw, tmp_path / "ds") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "discovery with adapter 'native' failed" in err


def test_nonfinite_frames_are_dropped_and_counted(tmp_path):
    from htdata.read.reader import DatasetReader

    p = np.random.default_rng(0).uniform(1000, 3072, size=(10, 16, 16)).astype(np.float32)
    p[[2, 7], 5, 9] = np.nan       # (5,9) is a live taxel (index finger, middle phalanx)
    p[4, 0, 2] = np.inf             # (0,2) is an unused cell: ignored
    raw = tmp_path / "raw"
    write_opentouch_scene(raw / "s.hdf5", [ot_clip("demo_01", 10, COLOURS[0], pressure=p)])
    write_opentouch_annotations(raw / "annotations.csv", [{"id": "s::demo_01", "action": "pour"}])
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, out) == 0
    reader = DatasetReader(out)
    ep = reader.episodes[0]
    # every video frame stays: the two without usable tactile as RGB-only samples, flagged and counted
    assert ep["num_frames"] == 10 and ep["dropped_frames"] == {"nonfinite_tactile:right": 2}
    assert ep["stats"]["frames_kept"] == 8 and ep["rgb_only_frames"] == {"nonfinite_tactile:right": 2}
    metas = [json.loads(reader.sample(i)["json"]) for i in range(10)]
    assert [m["source_frame"] for m in metas] == list(range(10))
    assert [i for i, m in enumerate(metas) if m.get("rgb_only")] == [2, 7]
    assert all("tactile_right.exr" not in reader.sample(i) for i in (2, 7))
    from htdata.read.torchdata import TactileFrameDataset
    assert sorted(int(x[0]) for x in TactileFrameDataset(out).items) == [0, 1, 3, 4, 5, 6, 8, 9]
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert report["dropped_frames"] == [{"episode_id": ep["episode_id"], "rgb_index": i,
                                         "reason": "nonfinite_tactile:right"} for i in (2, 7)]


def test_refuses_foreign_dirs_and_codec_changes(tmp_path, capsys):
    raw = make_native(tmp_path / "raw")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert ingest_cli("--pipeline", "native", raw, foreign) == 2
    assert "not empty" in capsys.readouterr().err and (foreign / "notes.txt").read_text() == "mine"
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), raw, out) == 0
    capsys.readouterr()
    other = small_pipeline(tmp_path, "native")
    other.write_text(other.read_text().replace('compression = "zip"', 'compression = "piz"'))
    assert 'compression = "piz"' in other.read_text()
    assert ingest_cli("--pipeline", other, raw, out) == 2
    err = capsys.readouterr().err
    assert "tactile.compression = 'zip'" in err and "'piz'" in err
    assert json.loads((out / "dataset.json").read_text())["version"] == 1     # nothing written


# --------------------------------------------------------------------------- crash + resume

def cli_subprocess(args, env_extra=None, **kw):
    env = {**os.environ, **(env_extra or {})}
    cmd = [sys.executable, "-m", "htdata.cli", "ingest", "--workers", "1", "--quiet", *map(str, args)]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def dataset_bytes(out: Path) -> dict[str, bytes]:
    manifest = json.loads((out / "dataset.json").read_text())
    files = {p.name: p.read_bytes() for p in (out / "shards").glob("*.tar")}
    for entry in manifest["segments"]:      # the version's records and index rows
        for key in ("records", "index"):
            files[entry[key]] = (out / entry[key]).read_bytes()
    return files


@pytest.fixture
def clean_run(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    ref = tmp_path / "clean"
    assert ingest_cli("--pipeline", pipe, raw, ref, workers=2) == 0   # the real process pool
    return raw, pipe, ref


def test_resume_after_worker_crash_equals_clean_run(tmp_path, clean_run):
    raw, pipe, ref = clean_run
    out = tmp_path / "crashed"
    proc = cli_subprocess(["--pipeline", pipe, raw, out], {"HTDATA_TEST_FAULT_UNIT": "1"})
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0, err
    assert (out / ".work" / "unit-000000.json").exists()
    assert not (out / ".work" / "unit-000001.json").exists() and not (out / "dataset.json").exists()
    assert list((out / "shards").glob(".shard-000001-*.tmp"))       # a half-written shard was left
    proc = cli_subprocess(["--pipeline", pipe, raw, out])
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert dataset_bytes(out) == dataset_bytes(ref)
    assert read_all(out).keys() == read_all(ref).keys()
    assert temp_leftovers(out) == []
    assert json.loads((out / "reports" / "ingest.json").read_text())["units_resumed"] == 1


def test_resume_after_kill_9_equals_clean_run(tmp_path, clean_run):
    raw, pipe, ref = clean_run
    out = tmp_path / "killed"
    proc = cli_subprocess(["--pipeline", pipe, raw, out], {"HTDATA_TEST_FAULT_UNIT": "1",
                                                           "HTDATA_TEST_FAULT": "hang"},
                          start_new_session=True)
    deadline = time.time() + 90
    try:
        while not list((out / "shards").glob(".shard-000001-*.tmp")):
            assert proc.poll() is None and time.time() < deadline, "ingest ended before it could be killed"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)   # kill -9 the CLI and its worker processes
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "dataset.json").exists()
    # a stale record from a different run must not be trusted: corrupt a finished shard too
    shard0 = next((out / "shards").glob("shard-000000-000.tar"))
    data = bytearray(shard0.read_bytes())
    data[700] ^= 0xFF
    shard0.write_bytes(bytes(data))
    proc = cli_subprocess(["--pipeline", pipe, raw, out])
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert dataset_bytes(out) == dataset_bytes(ref)
    assert temp_leftovers(out) == []


def test_changed_source_redoes_only_its_unit(tmp_path, clean_run):
    raw, pipe, ref = clean_run
    out = tmp_path / "again"
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    extra = tmp_path / "raw" / "z_scene.hdf5"
    write_opentouch_scene(extra, [ot_clip("demo_01", 9, COLOURS[3])])
    with open(tmp_path / "raw" / "annotations.csv", "a") as f:
        f.write("z_scene::demo_01,lift,,,,\n")
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    report = json.loads((out / "reports" / "ingest.json").read_text())
    # one unit per episode: only the new episode's unit exists and runs; the others are reused as committed
    assert report["units"] == 1 and report["units_run"] == 1 and report["samples"] == 9
    assert report["episodes_unchanged"] == 3 and report["version"] == 2
    assert len(read_all(out)) == 48


# --------------------------------------------------------------------------- progress + timing

TIMING_KEYS = {"frames", "total_s", "worker_s", "worker_cpu_s", "hash_s", "decode_s", "resize_s", "normalise_s", "rasterise_s",
               "encode_s", "write_s", "other_s"}
DRIVER_KEYS = {"plan_s", "run_s", "commit_s"}
DRIVER_CPU_KEYS = {"plan_cpu_s", "run_cpu_s", "commit_cpu_s"}     # the driver process's own CPU per phase
REST_KEYS = {"rest_s", "rest_cpu_s", "rest_recordings", "rest_gloves"}   # the pooled glove rest (part of plan)


def test_progress_events_arrive_per_episode_from_the_process_pool(tmp_path, monkeypatch):
    from htdata import ingest as ingest_module

    events, finished = [], []
    original_event, original_done = ingest_module.EpisodeProgress.event, ingest_module.EpisodeProgress.unit_done

    def record_event(self, event):
        events.append(event)
        original_event(self, event)

    def record_done(self, task, record):
        original_done(self, task, record)
        finished.append((self.done, self.frames))

    monkeypatch.setattr(ingest_module.EpisodeProgress, "event", record_event)
    monkeypatch.setattr(ingest_module.EpisodeProgress, "unit_done", record_done)
    raw = make_opentouch(tmp_path / "raw", bad=True)
    assert ingest_cli("--allow-failures", "--pipeline", small_pipeline(tmp_path, "opentouch", 16), raw,
                      tmp_path / "ds", workers=2) == 0
    by_episode = {e["episode_id"]: e["frames"] for e in events}
    assert len(events) == 6 and by_episode == {
        "ot-home_kitchen_p1-demo_01": 12, "ot-home_kitchen_p1-demo_02": 7, "ot-home_kitchen_p1-demo_003": 20,
        "ot-office_desk_p2-demo_01": 0, "ot-office_desk_p2-demo_02": 0, "ot-office_desk_p2-demo_03": 0}
    assert finished[-1] == (6, 39)      # reconciled: every episode counted once, every written frame


def test_episode_progress_reconciles_missing_late_and_repeated_events():
    from htdata.format.mapstorage import MapStorage
    from htdata.ingest import EpisodeProgress, UnitTask

    def task(unit, n):
        return UnitTask(unit=unit, out="", pipeline={}, pipeline_path="", root="", episodes=[None] * n,
                        maps=MapStorage.STORED)

    tasks = [task(0, 2), task(1, 3), task(2, 1)]
    p = EpisodeProgress(tasks, done_units={2}, enabled=False)
    assert p.done == 1
    p.event({"unit": 0, "frames": 5})
    p.event({"unit": 0, "frames": 4})
    p.event({"unit": 0, "frames": 5})          # a retried unit repeats an event: capped at 2 episodes
    assert (p.done, p.frames) == (3, 9)
    p.unit_done(tasks[0], {"frames": 8})
    assert (p.done, p.frames) == (3, 8)        # frames corrected to what the unit wrote
    p.event({"unit": 0, "frames": 5})          # late event of a finished unit: ignored
    p.unit_done(tasks[1], {"frames": 7})   # no events at all (Ray): the unit result counts
    assert (p.done, p.frames) == (6, 15)
    p.close()


def test_report_has_stage_timing(tmp_path):
    raw = make_touchanything(tmp_path / "raw")
    out = tmp_path / "ds"
    pipe = small_pipeline(tmp_path, "touchanything")
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    timing = json.loads((out / "reports" / "ingest.json").read_text())["timing"]
    assert set(timing) == TIMING_KEYS | DRIVER_KEYS | DRIVER_CPU_KEYS | REST_KEYS
    assert timing["frames"] == 11
    assert 0 <= timing["rest_s"] <= timing["plan_s"] and timing["rest_recordings"] == timing["rest_gloves"] == 0
    assert all(timing[k] >= 0 for k in DRIVER_CPU_KEYS)
    # the driver's phases add up to the wall time, and the units ran inside run_s
    assert sum(timing[k] for k in DRIVER_KEYS) == pytest.approx(timing["total_s"])
    assert timing["run_s"] >= timing["worker_s"]
    for stage in ("hash_s", "decode_s", "resize_s", "normalise_s", "rasterise_s", "encode_s", "write_s"):
        assert timing[stage] > 0, stage
    stages = sum(timing[k] for k in TIMING_KEYS - {"frames", "total_s", "worker_s", "worker_cpu_s", "other_s"})
    assert timing["worker_cpu_s"] > 0
    assert timing["other_s"] >= 0 and abs(stages + timing["other_s"] - timing["worker_s"]) < 1e-6
    assert timing["total_s"] >= timing["worker_s"]        # inline: the units ran inside the wall time
    records = [json.loads(p.read_text()) for p in sorted((out / ".work").glob("unit-*.json"))]
    assert sum(r["timing"]["encode_s"] for r in records) == pytest.approx(timing["encode_s"])
    # a fully resumed run processed no frame
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    resumed = json.loads((out / "reports" / "ingest.json").read_text())["timing"]
    assert resumed["frames"] == 0 and resumed["worker_s"] == 0 and resumed["decode_s"] == 0
    assert resumed["total_s"] > 0


def test_benchmark_maps_are_the_maps_ingest_stores(tmp_path):
    """The benchmarks read episodes through the ingest's own generator: same frames, same maps."""
    from htdata.benchmarks.sources import discover, episode_maps
    from htdata.read.reader import DatasetReader

    raw = make_touchanything(tmp_path / "raw")
    out = tmp_path / "ds"
    pipe = small_pipeline(tmp_path, "touchanything")
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    reader = DatasetReader(out)
    position = {e["episode_id"]: i for i, e in enumerate(reader.episodes)}
    cfg, adapter, refs = discover(str(pipe), raw)
    assert sorted(r.episode_id for r in refs) == sorted(position)
    for ref in refs:
        em = episode_maps(cfg, adapter, ref)
        first, n = reader.episode_range(position[ref.episode_id])
        assert n == len(em.rgb_index) and set(em.maps) == {"left", "right"}
        for k in range(n):
            d = reader.decoded(first + k)
            assert d["meta"]["source_frame"] == em.rgb_index[k]
            for hand, maps in em.maps.items():   # stored as EXR half: |error| <= 2**-11 in [0,1]
                np.testing.assert_allclose(d["tactile"][hand], maps[k], atol=5e-4)
