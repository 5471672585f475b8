"""`htdata export lerobot`: the export read back with pyarrow + PyAV (as LeRobot v3.0 documents it), not our reader.

The dataset: a two-glove recording (left 21x21, right 16x16) with a long episode id whose
gloves start late (RGB-only frames), and a glove-only recording (tactile-only frames).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
av = pytest.importorskip("av")

from htdata.cli import main as cli  # noqa: E402
from htdata.format.codec import decode_rgb  # noqa: E402
from htdata.format.table import RGB_MEMBER  # noqa: E402
from htdata.read.rawstream import paired_row  # noqa: E402
from htdata.read.reader import DatasetReader  # noqa: E402
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording  # noqa: E402
from tests.factories import PERIOD, commit_split, ingest_cli, small_pipeline  # noqa: E402

LONG = "rec_" + "a_very_long_recording_name_from_the_field_" * 3 + "end"   # 133 characters
FRAMES = 10
GLOVE_START = 3          # the gloves start at video frame 3: frames 0..2 are RGB-only


def two_glove_recording(folder: Path) -> None:
    rng = np.random.default_rng(7)
    t_video = np.arange(FRAMES, dtype=np.int64) * PERIOD
    t_glove = np.arange(GLOVE_START * PERIOD, FRAMES * PERIOD, 10_000_000, dtype=np.int64)    # 100 Hz
    frames = [np.ascontiguousarray(np.broadcast_to(
        np.array([20 * k, 255 - 20 * k, 128], np.uint8), (48, 64, 3))) for k in range(FRAMES)]
    write_native_recording(folder, NativeRecording(
        task="pour water", scene="lab", video_storage="jpeg", video_frames=frames, video_timestamps_ns=t_video,
        hands={"left": NativeHand("touchanything_left_21x21",
                                  rng.uniform(0, 1, (t_glove.size, 21, 21)).astype(np.float32), t_glove),
               "right": NativeHand("opentouch_right_16x16",
                                   rng.uniform(0, 3072, (t_glove.size, 16, 16)).astype(np.float32), t_glove)}))


def glove_only_recording(folder: Path, rows: int = 8) -> None:
    t_glove = np.arange(rows, dtype=np.int64) * PERIOD                                        # 30 Hz
    values = np.random.default_rng(3).uniform(0, 3072, (rows, 16, 16)).astype(np.float32)
    write_native_recording(folder, NativeRecording(
        task="squeeze", scene="lab", video_storage="none", video_frames=[], video_timestamps_ns=np.zeros(0, np.int64),
        hands={"right": NativeHand("opentouch_right_16x16", values, t_glove)}))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("lerobot")
    two_glove_recording(tmp / "raw" / LONG)
    glove_only_recording(tmp / "raw" / "rec_glove")
    out = tmp / "ds"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp, 'native')}={tmp / 'raw'}", out) == 0
    return out


def read_export(root: Path) -> dict:
    info = json.loads((root / "meta/info.json").read_text())
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    data = pa.concat_tables([pq.read_table(p) for p in sorted((root / "data").rglob("*.parquet"))])
    tasks = pq.read_table(root / "meta/tasks.parquet").to_pydict()
    return {"info": info, "episodes": episodes, "data": data.to_pydict(),
            "tasks": dict(zip(tasks["task_index"], tasks["task"]))}


def video(root: Path, info: dict, ep: dict, key: str) -> tuple[np.ndarray, list[np.ndarray]]:
    path = root / info["video_path"].format(video_key=key, chunk_index=ep[f"videos/{key}/chunk_index"],
                                            file_index=ep[f"videos/{key}/file_index"])
    with av.open(str(path)) as c:
        frames = [(float(f.pts * f.time_base), f.to_ndarray(format="rgb24")) for f in c.decode(video=0)]
    frames.sort(key=lambda x: x[0])
    return np.array([t for t, _ in frames]), [f for _, f in frames]


def test_export_structure_and_values(dataset, tmp_path):
    out = tmp_path / "lr"
    assert cli(["export", "lerobot", str(dataset), str(out), "--quiet", "--maps"]) == 0
    for rel in ("meta/info.json", "meta/stats.json", "meta/tasks.parquet", "meta/episodes/chunk-000/file-000.parquet",
                "data/chunk-000/file-000.parquet", "meta/htdata/episodes.jsonl",
                "meta/htdata/layout_touchanything_left_21x21_coverage.png", "meta/htdata/region_map.png"):
        assert (out / rel).is_file(), rel
    assert not list(tmp_path.glob(".lr.partial*"))
    ex = read_export(out)
    info, data = ex["info"], ex["data"]
    feats = info["features"]
    assert info["codebase_version"] == "v3.0" and info["fps"] == 30
    assert feats["observation.tactile.left.raw"]["shape"] == [441]
    assert feats["observation.tactile.left.raw"]["info"]["grid"] == [21, 21]
    assert feats["observation.tactile.right.raw"]["shape"] == [256]
    assert feats["observation.present"]["names"] == ["egocentric", "tactile.left.raw", "tactile.right.raw"]
    assert {"observation.images.egocentric", "observation.tactile.left.map"} <= {
        k for k, f in feats.items() if f["dtype"] == "video"}

    reader = DatasetReader(dataset)
    ids = [json.loads(line)["episode_id"] for line in (out / "meta/htdata/episodes.jsonl").read_text().splitlines()]
    assert sorted(ids) == sorted(ep["episode_id"] for ep in reader.episodes) and f"nat-{LONG}" in ids
    assert [e["htdata/episode_id"] for e in ex["episodes"]] == ids
    assert len(data["index"]) == info["total_frames"] == len(reader)
    assert data["index"] == list(range(len(reader)))
    stats = json.loads((out / "meta/stats.json").read_text())
    n_rgb_only = n_tactile_only = 0
    for ep in ex["episodes"]:
        e, lo, hi = ep["episode_index"], ep["dataset_from_index"], ep["dataset_to_index"]
        eid = ids[e]
        first, n = reader.episode_range(eid)
        assert hi - lo == n and ep["length"] == n
        assert ex["tasks"][data["task_index"][lo]] == reader.episodes[reader.episode_position(eid)]["task"]
        vt, frames = video(out, info, ep, "observation.images.egocentric")
        assert len(frames) == n
        # rows on LeRobot's exact 1/fps grid; on these regular clocks every stored frame once, in order
        np.testing.assert_array_equal(data["timestamp"][lo:hi], (np.arange(n) / 30).astype(np.float32))
        assert data["htdata.frame_index"][lo:hi] == list(range(n)) == data["frame_index"][lo:hi]
        for r in range(lo, hi):
            f = data["htdata.frame_index"][r]
            members = reader.sample(first + f)
            meta = json.loads(members["json"])
            # the row's tick is its stored frame's time on the source clock (half a period at most)
            assert data["timestamp"][r] == pytest.approx((meta["t_rgb_ns"] - json.loads(
                reader.sample(first)["json"])["t_rgb_ns"]) / 1e9, abs=0.5 / 30)
            k = int(np.argmin(np.abs(vt - (ep["videos/observation.images.egocentric/from_timestamp"]
                                           + data["timestamp"][r]))))
            assert abs(vt[k] - ep["videos/observation.images.egocentric/from_timestamp"] - data["timestamp"][r]) < 1e-4
            present = dict(zip(feats["observation.present"]["names"], data["observation.present"][r]))
            assert present["egocentric"] == (RGB_MEMBER in members)
            if RGB_MEMBER in members:
                diff = np.abs(frames[k].astype(int) - decode_rgb(members[RGB_MEMBER]).astype(int))
                assert diff.mean() < 4.0
            else:                                   # tactile-only: black (no earlier RGB in the episode)
                n_tactile_only += 1
                assert frames[k].max() <= 16
            for hand, grid in (("left", (21, 21)), ("right", (16, 16))):
                row = np.asarray(data[f"observation.tactile.{hand}.raw"][r], np.float32).reshape(grid)
                if f"raw_{hand}.npy" in members:
                    assert present[f"tactile.{hand}.raw"]
                    want = paired_row(members, hand, "test").astype(np.float32)
                    assert np.array_equal(row.view(np.uint32), want.view(np.uint32))   # raw rows exact
                else:
                    assert not present[f"tactile.{hand}.raw"] and not row.any()
            if not any(present[f"tactile.{h}.raw"] for h in ("left", "right")):
                n_rgb_only += 1
    assert n_rgb_only == GLOVE_START and n_tactile_only == 8
    # stats: real rows only (zeros of absent frames left out), per element, LeRobot's keys
    left = np.asarray(data["observation.tactile.left.raw"], np.float32)
    real = left[[p[1] for p in data["observation.present"]]]
    s = stats["observation.tactile.left.raw"]
    assert set(s) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
    assert s["count"] == [len(real)]
    np.testing.assert_allclose(s["mean"], real.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(s["max"], real.max(0))
    assert np.asarray(stats["observation.images.egocentric"]["mean"]).shape == (3, 1, 1)


def test_split_part_export_and_its_record(dataset, tmp_path):
    reader = DatasetReader(dataset)
    ids = [ep["episode_id"] for ep in reader.episodes]
    commit_split(dataset, "main", {"train": [ids[1]], "test": [ids[0]]})
    out = tmp_path / "part"
    assert cli(["export", "lerobot", str(dataset), str(out), "--split", "main", "--part", "test", "--quiet"]) == 0
    ex = read_export(out)
    assert [e["htdata/episode_id"] for e in ex["episodes"]] == [ids[0]]
    assert ex["info"]["splits"] == {"test": "0:1"}
    record = json.loads((out / "meta/htdata/split.json").read_text())
    assert record["exported_parts"] == ["test"] and record["assignment"]["parts"]["train"]["episodes"] == [ids[1]]
    whole = tmp_path / "whole"
    assert cli(["export", "lerobot", str(dataset), str(whole), "--split", "main", "--quiet", "--version", "v2"]) == 0
    assert read_export(whole)["info"]["splits"] == {"train": "0:1", "test": "1:2"}


def test_resampling_takes_the_nearest_frame(dataset, tmp_path):
    out = tmp_path / "r15"
    assert cli(["export", "lerobot", str(dataset), str(out), "--fps", "15", "--quiet"]) == 0
    ex = read_export(out)
    reader = DatasetReader(dataset)
    data = ex["data"]
    for ep in ex["episodes"]:
        lo, hi = ep["dataset_from_index"], ep["dataset_to_index"]
        first, n = reader.episode_range(ep["htdata/episode_id"])
        t0 = json.loads(reader.sample(first)["json"])["t_rgb_ns"]
        src = np.array([(json.loads(reader.sample(i)["json"])["t_rgb_ns"] - t0) / 1e9 for i in range(first, first + n)])
        ts = np.asarray(data["timestamp"][lo:hi], np.float64)
        np.testing.assert_allclose(ts, np.arange(hi - lo) / 15, atol=1e-6)
        for r, t in zip(range(lo, hi), ts):
            k = int(np.argmin(np.abs(src - t)))
            assert data["htdata.frame_index"][r] == k
            members = reader.sample(first + k)
            if "raw_right.npy" in members:
                want = paired_row(members, "right", "test").astype(np.float32).ravel()
                assert np.array_equal(np.asarray(data["observation.tactile.right.raw"][r], np.float32), want)


def test_errors_are_one_line_and_leave_nothing(dataset, tmp_path, capsys):
    out = tmp_path / "x"
    out.mkdir()
    (out / "recording.json").write_text("{}")     # a folder of recordings, not an export
    for force in ([], ["--force"]):                 # the same advice with or without --force, and no empty bar
        assert cli(["export", "lerobot", str(dataset), str(out), *force]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is not a previous htdata export" in err and "choose another OUT" in err, err
        assert "pass --force" not in err and "frame" not in err   # no bar
    assert (out / "recording.json").read_text() == "{}"
    assert cli(["export", "lerobot", str(dataset), str(tmp_path / "y"), "--part", "test", "--quiet"]) == 2
    assert "--part needs --split" in capsys.readouterr().err
    assert cli(["export", "lerobot", str(dataset), str(tmp_path / "z"), "--split", "nope", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope" in err
    assert not (tmp_path / "z").exists() and not list(tmp_path.glob(".z.partial*"))


def tree(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


def test_export_is_read_only_and_atomic(dataset, tmp_path, monkeypatch):
    from htdata.export import lerobot as lerobot_export

    before = tree(dataset)
    out = tmp_path / "lr"
    # an interrupted export (Ctrl-C in the middle of an episode) leaves no OUT and no partial folder
    calls = {"n": 0}
    real_add = lerobot_export.VideoWriter.add

    def interrupted(self, *a, **kw):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real_add(self, *a, **kw)

    monkeypatch.setattr(lerobot_export.VideoWriter, "add", interrupted)
    with pytest.raises(KeyboardInterrupt):
        lerobot_export.export_lerobot(lerobot_export.LeRobotExportConfig(dataset=str(dataset), out=out))
    assert not out.exists() and not (tmp_path / ".lr.partial").exists()
    monkeypatch.setattr(lerobot_export.VideoWriter, "add", real_add)
    # a kill -9 leaves the hidden partial folder: the next export clears it and finishes
    (tmp_path / ".lr.partial" / "data").mkdir(parents=True)
    (tmp_path / ".lr.partial" / "data" / "junk.parquet").write_bytes(b"half written")
    assert cli(["export", "lerobot", str(dataset), str(out), "--quiet"]) == 0
    assert not (tmp_path / ".lr.partial").exists() and not (out / "data" / "junk.parquet").exists()
    assert json.loads((out / "meta/info.json").read_text())["total_frames"] == len(DatasetReader(dataset))
    assert tree(dataset) == before                       # DATASET untouched: no file written or changed


def test_a_gap_in_the_source_clock_repeats_the_frames_beside_it(tmp_path):
    t = np.delete(np.arange(10, dtype=np.int64) * PERIOD, [5, 6])        # the glove missed two rows
    values = np.random.default_rng(5).uniform(0, 3072, (t.size, 16, 16)).astype(np.float32)
    write_native_recording(tmp_path / "raw" / "rec_gap", NativeRecording(
        task="squeeze", scene="lab", video_storage="none", video_frames=[], video_timestamps_ns=np.zeros(0, np.int64),
        hands={"right": NativeHand("opentouch_right_16x16", values, t)}))
    ds = tmp_path / "ds"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp_path, 'native')}={tmp_path / 'raw'}", ds) == 0
    out = tmp_path / "lr"
    assert cli(["export", "lerobot", str(ds), str(out), "--quiet", "--fps", "30"]) == 0
    data = read_export(out)["data"]
    # stored frames sit at ticks 0-4 and 7-9; ticks 5 and 6 take the nearest stored frame on either side
    assert data["htdata.frame_index"] == [0, 1, 2, 3, 4, 4, 5, 5, 6, 7]
    np.testing.assert_array_equal(data["timestamp"], (np.arange(10) / 30).astype(np.float32))
    raw = np.asarray(data["observation.tactile.right.raw"], np.float32).reshape(10, 16, 16)
    assert np.array_equal(raw[5], values[4]) and np.array_equal(raw[6], values[5]) and np.array_equal(raw[9], values[7])


def test_a_glove_only_dataset_exports_no_video_feature(tmp_path):
    # before: an all-black observation.images.egocentric mp4 per episode and a present flag that is never true
    glove_only_recording(tmp_path / "raw" / "rec_a")
    glove_only_recording(tmp_path / "raw" / "rec_b", rows=5)
    ds = tmp_path / "ds"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp_path, 'native')}={tmp_path / 'raw'}", ds) == 0
    out = tmp_path / "lr"
    assert cli(["export", "lerobot", str(ds), str(out)]) == 0
    ex = read_export(out)
    feats = ex["info"]["features"]
    assert not [k for k, f in feats.items() if f["dtype"] == "video"]
    assert not (out / "videos").exists() and not any(k.startswith("videos/") for k in ex["episodes"][0])
    assert feats["observation.present"]["names"] == ["tactile.right.raw"]
    assert all(p == [True] for p in ex["data"]["observation.present"])
    with DatasetReader(ds) as r:
        first = r.episode_range("nat-rec_b")[0]
        want = paired_row(r.sample(first + 2), "right", "x")
    e = next(e for e in ex["episodes"] if e["htdata/episode_id"] == "nat-rec_b")
    row = ex["data"]["observation.tactile.right.raw"][e["dataset_from_index"] + 2]
    assert np.array_equal(np.asarray(row, np.float32), want.astype(np.float32).ravel())
    # --maps still writes the map videos (and only those)
    assert cli(["export", "lerobot", str(ds), str(tmp_path / "lr_maps"), "--maps"]) == 0
    info = json.loads((tmp_path / "lr_maps" / "meta/info.json").read_text())
    assert [k for k, f in info["features"].items() if f["dtype"] == "video"] == ["observation.tactile.right.map"]


def test_force_replaces_only_a_previous_export(dataset, tmp_path, capsys):
    """Issue 26 item 7: before, `--force data/ds data` deleted the dataset and a note beside it."""
    import shutil

    home = tmp_path / "data"
    ds = home / "ds"
    shutil.copytree(dataset, ds)
    (home / "notes.txt").write_text("mine")
    before = tree(ds)

    def refused(out, *flags):
        assert cli(["export", "lerobot", str(ds), str(out), "--quiet", *flags]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        return err

    assert "holds DATASET" in refused(home, "--force")                  # the folder holding the dataset
    (home / "other").mkdir()
    (home / "other" / "keep.txt").write_text("keep")
    assert "not a previous htdata export" in refused(home / "other", "--force")
    assert "is a file" in refused(home / "notes.txt", "--force")
    (tmp_path / "link").symlink_to(home / "other")
    assert "is a symlink" in refused(tmp_path / "link")
    assert "inside DATASET" in refused(ds / "lr", "--force")
    assert tree(ds) == before and (home / "notes.txt").read_text() == "mine"
    assert (home / "other" / "keep.txt").exists()
    # a previous export is replaced; one that somebody put a dataset into is not
    out = tmp_path / "lr"
    assert cli(["export", "lerobot", str(ds), str(out), "--quiet"]) == 0
    assert (out / ".htdata-export.json").is_file()
    assert "holds a previous htdata export; pass --force to replace it" in refused(out)
    assert cli(["export", "lerobot", str(ds), str(out), "--quiet", "--force"]) == 0
    shutil.copytree(dataset, out / "inner")
    assert "holds an htdata dataset" in refused(out, "--force")
    assert (out / "inner" / "dataset.json").is_file()
