"""`htdata sample OUT`: the corpus plan and the files written in the three formats."""

from __future__ import annotations

import csv
import json
from collections import Counter
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from htdata.cli import main as htdata_main
from htdata.synthetic.corpus import (
    COMPLETE_MARKER,
    WORLD_VERSION,
    CorpusConfig,
    corpus_complete,
    corpus_identity,
    plan_corpus,
    write_corpus,
)
from htdata.synthetic.tasks import TASKS

OT_KEYS = {"camera_poses", "labels", "rgb_images_jpeg", "right_hand_landmarks", "right_palm_pos",
           "right_wrist_pos", "right_pressure", "timestamps"}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("corpus") / "raw"
    assert htdata_main(["sample", str(out), "--scale", "tiny", "--quiet"]) == 0
    return out


def _video_frames(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames


# ---- plan -------------------------------------------------------------------------

def test_formats_are_registered_adapters_with_a_writer_and_plans():
    from htdata.source.adapters import ADAPTERS
    from htdata.synthetic import corpus

    assert corpus.FORMATS == ("opentouch", "touchanything", "native")
    assert list(corpus.FORMATS) == [name for name in ADAPTERS if name in corpus.FORMATS]   # registry order
    assert set(corpus._WRITERS) == set(corpus.FORMATS)
    for scale in corpus.SCALES:
        assert set(corpus._PLANS[scale]) == set(corpus.FORMATS), scale


def test_small_plan_supports_task_splits():
    plan = plan_corpus(CorpusConfig(out=Path("unused"), scale="small"))
    tasks = {ep.spec.task for ep in plan}
    scenes = {ep.spec.scene for ep in plan}
    assert len(tasks) >= 6 and set(tasks) == set(TASKS) and len(scenes) >= 3
    per = Counter((ep.fmt, ep.spec.task) for ep in plan)
    for task in tasks:  # a 9:1 split per task and an OOD task need >= 3 episodes in some format
        assert max(per[(fmt, task)] for fmt in ("opentouch", "touchanything", "native")) >= 3, task
    assert 40 <= len(plan) <= 60
    assert 2500 <= sum(ep.spec.n_frames for ep in plan) <= 5000
    ot = [ep for ep in plan if ep.fmt == "opentouch"]
    assert all(47 <= ep.spec.n_frames <= 90 for ep in ot)
    assert len({ep.spec.scene for ep in ot}) == 3
    # names unique per container
    assert len({(ep.fmt, ep.spec.scene if ep.fmt == "opentouch" else "", ep.name) for ep in plan}) == len(plan)
    native = [ep for ep in plan if ep.fmt == "native"]
    assert any(ep.spec.hands == ("left", "right") for ep in native)
    assert any(ep.spec.hands == ("right",) for ep in native)


def test_plan_is_deterministic_and_seeded():
    a = plan_corpus(CorpusConfig(out=Path("x"), seed=0, scale="small"))
    b = plan_corpus(CorpusConfig(out=Path("y"), seed=0, scale="small"))
    c = plan_corpus(CorpusConfig(out=Path("x"), seed=1, scale="small"))
    assert [(e.name, e.spec) for e in a] == [(e.name, e.spec) for e in b]
    assert [e.spec.seed for e in a] != [e.spec.seed for e in c]


def test_config_validation():
    with pytest.raises(ValueError, match="scale"):
        CorpusConfig(out=Path("x"), scale="huge").validate()
    with pytest.raises(ValueError, match="formats"):
        CorpusConfig(out=Path("x"), formats=("opentouch", "kinect")).validate()
    with pytest.raises(ValueError, match="formats"):
        CorpusConfig(out=Path("x"), formats=()).validate()
    with pytest.raises(ValueError, match="seed"):
        CorpusConfig(out=Path("x"), seed=-1).validate()


# ---- OpenTouch ----------------------------------------------------------------------

def test_opentouch_files_keys_units_and_annotations(tiny):
    files = sorted((tiny / "opentouch").glob("*.hdf5"))
    assert len(files) == 2
    with open(tiny / "opentouch" / "annotations.csv", newline="") as f:
        rows = {r["id"]: r for r in csv.DictReader(f)}
    paddings = set()
    for path in files:
        with h5py.File(path, "r") as h5:
            assert {"calibration", "data", "transform_slam_to_rgb"} <= set(h5)
            assert h5["calibration/rgb/image_size"][()].tolist() == [512, 512]
            for demo, g in h5["data"].items():
                paddings.add(len(demo.split("_")[1]))
                assert set(g) == OT_KEYS
                p = g["right_pressure"][()]
                ts = g["timestamps"][()]
                t = len(ts)
                assert p.shape == (t, 16, 16) and p.dtype == np.float32 and 47 <= t <= 90
                assert p.min() >= 0 and p.max() <= 3072
                assert np.median(p) > 3000  # mostly unloaded: inverted units
                assert p.min() < 2000       # but somewhere pressed hard
                assert ts.dtype == np.int64 and np.all(np.diff(ts) > 0)
                assert 30e6 < np.median(np.diff(ts)) < 36e6  # 30 fps in ns
                assert g["rgb_images_jpeg"].shape == (t,)
                assert g["labels"].dtype.names == ("low_light", "hand_out_of_frame")
                row = rows[f"{path.stem}::{demo}"]
                assert row["action"] in TASKS
    assert paddings == {2, 3}  # demo_07 in one file, demo_007 in the other
    assert len(rows) == 4


def test_opentouch_pinch_contact_on_thumb_and_index_tips(tiny):
    with open(tiny / "opentouch" / "annotations.csv", newline="") as f:
        pinch = [r["id"] for r in csv.DictReader(f) if r["action"] == "pinch_pick"]
    scene, demo = pinch[0].split("::")
    with h5py.File(tiny / "opentouch" / f"{scene}.hdf5", "r") as h5:
        p = h5[f"data/{demo}/right_pressure"][()]
    contact = np.clip((3072 - p) / 3072, 0, 1)
    peak = contact[int(np.argmax(contact.sum(axis=(1, 2))))]
    assert peak[0:3, 9:11].max() > 0.3 and peak[12:16, 13:16].max() > 0.3  # index / thumb distal
    assert peak[9:16, 0:11].max() < 0.05                                   # palm untouched (noise)
    assert contact.max(axis=(1, 2)).min() < 0.05    # idle somewhere (timings vary: not always the first frame)


def test_opentouch_jpegs_are_stored_bgr_swapped(tiny):
    with open(tiny / "opentouch" / "annotations.csv", newline="") as f:
        pinch = [r["id"] for r in csv.DictReader(f) if r["action"] == "pinch_pick"]
    scene, demo = pinch[0].split("::")
    with h5py.File(tiny / "opentouch" / f"{scene}.hdf5", "r") as h5:
        buf = np.asarray(h5[f"data/{demo}/rgb_images_jpeg"][0])
    arr = cv2.imdecode(buf, cv2.IMREAD_COLOR)  # cv2 hands back the stored channel order
    assert arr.shape == (512, 512, 3)
    # The red sphere: stored swapped, so channel 0 holds red (a correct JPEG would give B first).
    red_first = (arr[..., 0] > 170) & (arr[..., 1] < 80) & (arr[..., 2] < 90)
    red_last = (arr[..., 2] > 170) & (arr[..., 1] < 80) & (arr[..., 0] < 90)
    assert red_first.sum() > 50 and red_last.sum() == 0


def test_same_seed_same_opentouch_bytes(tmp_path):
    def load(out):
        got = {}
        for path in sorted((out / "opentouch").glob("*.hdf5")):
            with h5py.File(path, "r") as h5:
                for demo, g in h5["data"].items():
                    got[(path.name, demo, "p")] = g["right_pressure"][()]
                    got[(path.name, demo, "jpg")] = [bytes(np.asarray(b)) for b in g["rgb_images_jpeg"]]
        return got

    outs = []
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        cfg = CorpusConfig(out=tmp_path / name, seed=seed, scale="tiny", formats=("opentouch",), progress=False)
        write_corpus(cfg)
        outs.append(load(tmp_path / name))
    a, b, c = outs
    assert a.keys() == b.keys()
    for key in a:
        if key[2] == "p":
            np.testing.assert_array_equal(a[key], b[key])
        else:
            assert a[key] == b[key]
    p_keys = [k for k in a if k[2] == "p"]
    assert any(k not in c or not np.array_equal(a[k], c[k]) for k in p_keys)


# ---- TouchAnything ------------------------------------------------------------------

def test_touchanything_episodes(tiny):
    root = tiny / "touchanything"
    split = json.loads((root / "split.json").read_text())
    assert set(split) == {"train", "val", "test_seen", "test_unseen"}
    episodes = sorted(p.parent for p in root.glob("*/*/*/pressure_grids.npz"))
    assert len(episodes) == 2
    listed = {"/".join(Path(p).parts[-3:]) for paths in split.values() for p in paths}
    assert listed == {"/".join(e.parts[-3:]) for e in episodes}
    extra_frames = []
    for ep in episodes:
        names = {p.name for p in ep.iterdir()}
        assert {"chest.mp4", "left.mp4", "right.mp4", "pressure_grids.npz", "jq_pressure.json",
                "wilor_hands.json", "hamer_hands.json", "rokoko_hands.json", "vive_poses.json"} <= names
        with np.load(ep / "pressure_grids.npz") as z:
            left, right = z["left_pressure_grid"], z["right_pressure_grid"]
        t = left.shape[0]
        for g in (left, right):
            assert g.shape == (t, 21, 21)
            assert (np.isnan(g).sum(axis=(1, 2)) == 224).all()
            assert np.nanmin(g) >= 0 and np.nanmax(g) <= 1
        rows = [json.loads(line) for line in (ep / "jq_pressure.json").read_text().splitlines()]
        assert len(rows) == t and [r["frame_index"] for r in rows] == list(range(t))
        ts = np.array([r["ts"] for r in rows])
        assert ts[0] > 1.6e9 and np.all(np.diff(ts) >= 0)
        assert len(rows[0]["sensor_left"]) == 256
        frames = _video_frames(ep / "chest.mp4")
        assert frames[0].shape == (480, 640, 3)
        extra_frames.append(len(frames) - t)
    assert all(0 <= e <= 2 for e in extra_frames)
    assert any(e > 0 for e in extra_frames)  # the release quirk is present


def test_touchanything_right_grid_stored_mirrored(tiny):
    ep = next((tiny / "touchanything").glob("*/pinch_pick/*"))
    with np.load(ep / "pressure_grids.npz") as z:
        right = z["right_pressure_grid"]
    peak = right[int(np.nanargmax(np.nansum(right[:, :6], axis=(1, 2))))]
    # right index tip sits at stored columns 5-7 (left layout: 13-15)
    assert np.nanmax(peak[2:6, 5:8]) > 0.3 and np.nanmax(peak[2:6, 13:16]) < 0.05


# ---- native -------------------------------------------------------------------------

def test_native_recordings_clocks(tiny):
    recs = sorted((tiny / "native").iterdir())
    assert len(recs) == 2
    seen_hands = set()
    for rec in recs:
        doc = json.loads((rec / "recording.json").read_text())
        assert doc["format"] == "htdata-native" and doc["task"] in TASKS
        video_ts = np.load(rec / doc["video"]["timestamps"])
        assert 30e6 < np.median(np.diff(video_ts)) < 36e6
        frames = _video_frames(rec / doc["video"]["file"])
        assert len(frames) == len(video_ts) and frames[0].shape == (480, 480, 3)
        seen_hands.add(tuple(sorted(doc["hands"])))
        for hand, h in doc["hands"].items():
            with np.load(rec / h["file"]) as z:
                values, ts = z["values"], z["timestamps_ns"]
            assert np.median(np.diff(ts)) == pytest.approx(10e6, rel=0.01)  # 100 Hz
            assert h["clock_offset_ns"] != 0
            on_video = ts + h["clock_offset_ns"]
            # same episode span on both clocks once the offset is applied
            assert abs(int(on_video[0]) - int(video_ts[0])) < 20e6
            grid = (16, 16) if h["layout"] == "opentouch_right_16x16" else (21, 21)
            assert values.shape == (len(ts), *grid)
            assert len(ts) > 3 * len(video_ts) - 5
    assert seen_hands == {("right",), ("left", "right")}


# ---- command ------------------------------------------------------------------------

def test_cli_refuses_to_overwrite_and_reports(tiny, capsys):
    assert htdata_main(["sample", str(tiny), "--scale", "tiny", "--quiet", "--formats", "native"]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_cli_writes_selected_formats_and_summary(tmp_path, capsys):
    out = tmp_path / "only_native"
    assert htdata_main(["sample", str(out), "--scale", "tiny", "--formats", "native"]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()      # a person's summary: what was written and the next command
    assert lines[0].startswith(f"wrote {out} in ") and "native" in lines[1] and "2 episodes" in lines[1]
    assert lines[-1].startswith(f"next: htdata ingest --pipeline native={out}/native DATASET")
    assert "htdata sample" in captured.err  # tqdm progress goes to stderr
    assert sorted(p.name for p in out.iterdir()) == [COMPLETE_MARKER, "native"]
    assert htdata_main(["sample", str(out), "--scale", "tiny", "--formats", "native",
                        "--overwrite", "--quiet", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["native"]["episodes"] == 2 and "opentouch" not in summary


def _stamps(root: Path) -> dict:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}


def test_reuse_keeps_a_finished_corpus_of_the_same_seed_and_rewrites_anything_else(tmp_path, capsys):
    out = tmp_path / "raw"
    args = ["sample", str(out), "--scale", "tiny", "--formats", "native", "--quiet", "--reuse"]
    assert htdata_main(args) == 0                               # nothing there: written
    cfg = CorpusConfig(out=out, scale="tiny", formats=("native",))
    assert corpus_complete(cfg)
    assert json.loads((out / COMPLETE_MARKER).read_text()) == {"seed": 0, "scale": "tiny", "formats": ["native"],
                                                                "world": WORLD_VERSION}
    before = _stamps(out)
    capsys.readouterr()
    assert htdata_main(args) == 0                               # finished, same seed: kept as is
    assert _stamps(out) == before and "reused" in capsys.readouterr().err
    assert not corpus_complete(CorpusConfig(out=out, scale="tiny", formats=("native",), seed=1))
    assert htdata_main([*args, "--seed", "1"]) == 0             # another seed: written again
    assert json.loads((out / COMPLETE_MARKER).read_text())["seed"] == 1
    (out / COMPLETE_MARKER).write_text("ok\n")                  # an old-style marker says nothing
    assert not corpus_complete(cfg)


def test_a_corpus_cut_short_has_no_marker_and_is_written_again(tmp_path, monkeypatch):
    from htdata.synthetic import corpus

    out = tmp_path / "raw"
    assert htdata_main(["sample", str(out), "--scale", "tiny", "--formats", "native", "--quiet"]) == 0

    def crash(*a, **k):
        raise KeyboardInterrupt("power cut")
    monkeypatch.setitem(corpus._WRITERS, "native", crash)
    with pytest.raises(KeyboardInterrupt):
        write_corpus(CorpusConfig(out=out, scale="tiny", formats=("native",), overwrite=True, progress=False))
    assert not (out / COMPLETE_MARKER).exists()               # the old marker went before the first byte
    monkeypatch.undo()
    assert htdata_main(["sample", str(out), "--scale", "tiny", "--formats", "native", "--quiet", "--reuse"]) == 0
    assert corpus_complete(CorpusConfig(out=out, scale="tiny", formats=("native",)))
    assert any((out / "native").iterdir())


def test_cli_rejects_unknown_format(tmp_path):
    with pytest.raises(SystemExit):
        htdata_main(["sample", str(tmp_path), "--formats", "opentouch,kinect"])


def test_cli_dry_run_lists_plan(tmp_path, capsys):
    assert htdata_main(["sample", str(tmp_path / "none"), "--dry-run", "--scale", "small"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(plan_corpus(CorpusConfig(out=tmp_path, scale="small")))
    assert not (tmp_path / "none").exists()


# ---- the mis-paired control corpus (--mispair-rgb) -----------------------------------------

def test_mispaired_plan_keeps_every_episode_and_films_another_task():
    normal = plan_corpus(CorpusConfig(out=Path("x"), scale="small"))
    control = plan_corpus(CorpusConfig(out=Path("x"), scale="small", mispair_rgb=True))
    assert [(e.fmt, e.name, e.spec) for e in control] == [(e.fmt, e.name, e.spec) for e in normal]
    assert not any("rgb_from" in e.extra for e in normal)
    for ep in control:
        other = ep.extra["rgb_from"]
        assert other != ep.spec and other.task != ep.spec.task
        assert other in [e.spec for e in control if e.fmt == ep.fmt]          # same format, same camera


def test_mispaired_corpus_has_the_same_touch_and_another_episodes_video(tiny, tmp_path, capsys):
    out = tmp_path / "control"
    args = ["sample", str(out), "--scale", "tiny", "--formats", "native", "--quiet", "--mispair-rgb"]
    assert htdata_main(args) == 0
    assert json.loads((out / COMPLETE_MARKER).read_text())["mispair_rgb"] is True
    assert not corpus_complete(CorpusConfig(out=out, scale="tiny", formats=("native",)))   # not a normal corpus
    capsys.readouterr()
    assert htdata_main([*args, "--reuse"]) == 0 and "reused" in capsys.readouterr().err
    for rec in sorted((tiny / "native").iterdir()):
        ours = out / "native" / rec.name
        for name in ("tactile_right.npz", "ego_timestamps.npy", "recording.json"):
            assert (ours / name).read_bytes() == (rec / name).read_bytes(), name
        a, b = _video_frames(rec / "ego.mp4"), _video_frames(ours / "ego.mp4")
        assert len(a) == len(b)
        assert np.mean([np.abs(x.astype(int) - y.astype(int)).mean() for x, y in zip(a, b)]) > 3


def test_episode_frames_sets_every_episode_s_length_and_nothing_else():
    """`--episode-frames LO,HI` (the driver bench's long episodes): each planned episode's frames drawn in LO..HI,
    the same episodes otherwise; without it the plan (and so the corpus) is the scale's, and its marker unchanged."""
    base = plan_corpus(CorpusConfig(out=Path("x"), scale="tiny"))
    long = plan_corpus(CorpusConfig(out=Path("x"), scale="tiny", episode_frames=(300, 330)))
    assert [(e.fmt, e.name, e.spec.task, e.spec.scene) for e in long] == [
        (e.fmt, e.name, e.spec.task, e.spec.scene) for e in base]
    assert all(300 <= e.spec.n_frames <= 330 for e in long) and all(e.spec.n_frames < 60 for e in base)
    assert {e.spec.n_frames for e in plan_corpus(CorpusConfig(out=Path("x"), scale="tiny",
                                                                episode_frames=(120, 120)))} == {120}
    assert "episode_frames" not in corpus_identity(CorpusConfig(out=Path("x"), scale="tiny").validate())
    assert corpus_identity(CorpusConfig(out=Path("x"), scale="tiny", episode_frames=(300, 330)).validate())[
        "episode_frames"] == [300, 330]
    for bad in ((1, 5), (40, 30), (10, 200_000)):
        with pytest.raises(ValueError, match="episode_frames"):
            CorpusConfig(out=Path("x"), episode_frames=bad).validate()


def test_sample_cli_episode_frames(tmp_path, capsys):
    """The CLI's N or LO,HI, refused with a usage error when malformed; a dry run prints the lengths."""
    assert htdata_main(["sample", str(tmp_path / "a"), "--scale", "tiny", "--formats", "native", "--dry-run",
                        "--episode-frames", "300"]) == 0
    lengths = [int(line.split("\t")[4]) for line in capsys.readouterr().out.splitlines()]
    assert lengths == [300, 300]
    for bad in ("0", "30,20", "x", "1,2,3"):
        with pytest.raises(SystemExit):
            htdata_main(["sample", str(tmp_path / "b"), "--episode-frames", bad])
