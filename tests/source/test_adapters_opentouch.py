"""OpenTouch-style adapter against fixtures written by htdata.synthetic.formats."""

from __future__ import annotations

import pickle

import h5py
import numpy as np
import pytest

from htdata.errors import EpisodeError
from htdata.source.adapters import get_adapter
from htdata.synthetic.formats import OpenTouchClip, write_opentouch_annotations, write_opentouch_scene

RED = (255, 0, 0)


def frames(t, colour=RED, size=64):
    for _ in range(t):
        yield np.full((size, size, 3), colour, dtype=np.uint8)


def pressure(t, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 3072, (t, 16, 16)).astype(np.float32)


def clip(demo_id, t=6, *, seed=0, colour=RED, left=False, start_ns=1_000_000_000):
    return OpenTouchClip(
        demo_id=demo_id,
        timestamps_ns=start_ns + np.arange(t, dtype=np.int64) * 33_333_333,
        right_pressure=pressure(t, seed),
        rgb_frames=frames(t, colour),
        left_pressure=pressure(t, seed + 100) if left else None,
    )


@pytest.fixture
def adapter():
    return get_adapter("opentouch")


def test_discovery_zero_padding_natural_sort_and_fallback_task(tmp_path, adapter):
    write_opentouch_scene(tmp_path / "home_kitchen_p3.hdf5", [clip("demo_10"), clip("demo_2"), clip("demo_007", t=4)])
    write_opentouch_scene(tmp_path / "sub" / "grocery_target_p1.hdf5", [clip("demo_01", t=3)])
    refs = adapter.discover(tmp_path, {})
    assert [r.episode_id for r in refs] == [
        "ot-grocery_target_p1-demo_01", "ot-home_kitchen_p3-demo_2",
        "ot-home_kitchen_p3-demo_007", "ot-home_kitchen_p3-demo_10",
    ]
    r = refs[2]
    assert r.source == "opentouch" and r.scene == "home_kitchen_p3"
    assert r.source_ref.endswith("home_kitchen_p3.hdf5::data/demo_007")
    assert r.est_frames == 4 and r.hands == ("right",)
    assert r.layouts == {"right": "opentouch_right_16x16"}
    assert r.task == "unlabelled" and "no annotations" in r.extra["task_source"]
    assert pickle.loads(pickle.dumps(r)) == r


def test_episode_id_is_sanitised(tmp_path, adapter):
    write_opentouch_scene(tmp_path / "home kitchen.p3.hdf5", [clip("demo_07")])
    (ref,) = adapter.discover(tmp_path, {})
    assert ref.episode_id == "ot-home_kitchen_p3-demo_07"


@pytest.mark.parametrize("suffix", [".csv", ".tsv"])
def test_task_from_annotations_any_padding(tmp_path, adapter, suffix):
    raw = tmp_path / "raw"
    write_opentouch_scene(raw / "office_p2.hdf5", [clip("demo_07"), clip("demo_008"), clip("demo_9"), clip("demo_10")])
    ann = tmp_path / f"labels{suffix}"
    write_opentouch_annotations(ann, [
        {"id": "office_p2::demo_07", "action": "pour water", "grip_type": "power"},
        {"id": "office_p2::demo_8", "action": "open drawer"},  # padding differs from the file
        {"id": "office_p2::demo_9", "action": "", "grip_type": "pinch"},
    ])
    refs = {r.episode_id: r for r in adapter.discover(raw, {"annotations": str(ann)})}
    assert refs["ot-office_p2-demo_07"].task == "pour water"
    assert refs["ot-office_p2-demo_008"].task == "open drawer"
    assert refs["ot-office_p2-demo_9"].task == "unlabelled"
    assert "empty" in refs["ot-office_p2-demo_9"].extra["task_source"]
    assert refs["ot-office_p2-demo_10"].task == "unlabelled"
    assert "missing" in refs["ot-office_p2-demo_10"].extra["task_source"]
    by_grip = {r.episode_id: r.task for r in adapter.discover(raw, {"annotations": str(ann), "task_field": "grip_type"})}
    assert by_grip["ot-office_p2-demo_07"] == "power"
    with pytest.raises(ValueError, match="no column 'verb'"):
        adapter.discover(raw, {"annotations": str(ann), "task_field": "verb"})


@pytest.mark.parametrize("swap_rb,channel_order,expected", [
    (True, "bgr", RED),     # release storage, default parameter
    (False, "rgb", RED),    # correctly stored JPEGs
    (True, "rgb", (0, 0, 255)),  # wrong parameter really swaps: proves the parameter acts
])
def test_rgb_colour_order(tmp_path, adapter, swap_rb, channel_order, expected):
    write_opentouch_scene(tmp_path / "s.hdf5", [clip("demo_1", t=3)], swap_rb=swap_rb)
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {"channel_order": channel_order}) as st:
        out = list(st.iter_rgb())
    assert [i for i, _ in out] == [0, 1, 2]
    for _, img in out:
        assert img.shape == (64, 64, 3) and img.dtype == np.uint8
        assert np.abs(img.reshape(-1, 3).mean(0) - np.array(expected)).max() < 4


def test_default_channel_order_is_bgr_and_bad_value_rejected(tmp_path, adapter):
    write_opentouch_scene(tmp_path / "s.hdf5", [clip("demo_1", t=2)])
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        _, img = next(st.iter_rgb())
    assert img[..., 0].mean() > 240 and img[..., 2].mean() < 15
    with pytest.raises(ValueError, match="channel_order"):
        adapter.open(ref, {"channel_order": "rbg"})


def test_tactile_rows_and_timestamps_equal_written(tmp_path, adapter):
    c = clip("demo_3", t=9, seed=5, start_ns=7)
    expected = c.right_pressure.copy()
    expected[2, 3, 4] = np.nan  # NaN must pass through untouched
    c.right_pressure = expected
    write_opentouch_scene(tmp_path / "s.hdf5", [c])
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        np.testing.assert_array_equal(st.rgb_timestamps_ns, c.timestamps_ns)
        np.testing.assert_array_equal(st.tactile_timestamps_ns["right"], c.timestamps_ns)
        assert st.tactile_timestamps_ns["right"].dtype == np.int64
        got = st.read_tactile("right", np.arange(9))
        assert got.dtype == np.float32 and got.shape == (9, 16, 16)
        np.testing.assert_array_equal(got, expected)
        idx = np.array([8, 2, 2, 5])  # unsorted + duplicated, non-contiguous
        np.testing.assert_array_equal(st.read_tactile("right", idx), expected[idx])
        assert st.read_tactile("right", np.array([], dtype=np.int64)).shape == (0, 16, 16)
        with pytest.raises(EpisodeError, match="no tactile stream for hand 'left'"):
            st.read_tactile("left", np.arange(2))
        with pytest.raises(EpisodeError, match="out of range"):
            st.read_tactile("right", np.array([9]))


def test_left_hand_needs_a_layout(tmp_path, adapter):
    write_opentouch_scene(tmp_path / "old_internal.hdf5", [clip("demo_1", t=4, left=True)])
    with pytest.raises(EpisodeError, match="opentouch_left_16x16") as err:
        adapter.discover(tmp_path, {})
    assert "old_internal.hdf5" in str(err.value) and "ot-old_internal-demo_1" in str(err.value)
    (right_only,) = adapter.discover(tmp_path, {"hands": ["right"]})
    assert right_only.hands == ("right",)
    # a layout given by params is used (any registered 16x16 layout works for the reader)
    (both,) = adapter.discover(tmp_path, {"layouts": {"left": "opentouch_right_16x16"}})
    assert both.hands == ("left", "right") and both.layouts["left"] == "opentouch_right_16x16"
    with h5py.File(tmp_path / "old_internal.hdf5") as f:
        left = f["data/demo_1/left_pressure"][()]
    with adapter.open(both, {}) as st:
        np.testing.assert_array_equal(st.read_tactile("left", np.arange(4)), left)


def test_truncated_hdf5_names_the_file(tmp_path, adapter):
    path = tmp_path / "broken_scene.hdf5"
    write_opentouch_scene(path, [clip("demo_1", t=5)])
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(EpisodeError, match="broken_scene.hdf5.*HDF5 does not open"):
        adapter.discover(tmp_path, {})


def test_corrupt_jpeg_names_file_episode_and_frame(tmp_path, adapter):
    path = tmp_path / "home_kitchen_p3.hdf5"
    write_opentouch_scene(path, [clip("demo_07", t=5)])
    with h5py.File(path, "r+") as f:
        f["data/demo_07/rgb_images_jpeg"][3] = np.frombuffer(b"\xff\xd8not a jpeg at all", dtype=np.uint8)
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        it = st.iter_rgb()
        assert [next(it)[0] for _ in range(3)] == [0, 1, 2]
        with pytest.raises(EpisodeError) as err:
            next(it)
    e = err.value
    assert (e.episode_id, e.frame) == ("ot-home_kitchen_p3-demo_07", 3)
    assert e.file.endswith("home_kitchen_p3.hdf5")
    assert str(e).endswith("home_kitchen_p3.hdf5 [ot-home_kitchen_p3-demo_07] frame 3: JPEG does not decode")
    again = pickle.loads(pickle.dumps(e))
    assert str(again) == str(e) and again.frame == 3


def test_zero_frame_clip_and_wrong_grid_shape(tmp_path, adapter):
    path = tmp_path / "s.hdf5"
    write_opentouch_scene(path, [clip("demo_0", t=0), clip("demo_1", t=4)])
    with h5py.File(path, "r+") as f:
        del f["data/demo_1/right_pressure"]
        f["data/demo_1/right_pressure"] = np.zeros((4, 16, 15), dtype=np.float32)
    empty, wrong = adapter.discover(tmp_path, {})
    assert empty.est_frames == 0
    with pytest.raises(EpisodeError, match=r"\[ot-s-demo_0\]: clip has zero frames"):
        adapter.open(empty, {})
    with pytest.raises(EpisodeError, match=r"\(4, 16, 15\) does not match layout 'opentouch_right_16x16'"):
        adapter.open(wrong, {})


def test_length_mismatch_aligned_on_shortest(tmp_path, adapter):
    path = tmp_path / "s.hdf5"
    write_opentouch_scene(path, [clip("demo_1", t=6)])
    with h5py.File(path, "r+") as f:
        ts = f["data/demo_1/timestamps"][()]
        del f["data/demo_1/timestamps"]
        f["data/demo_1/timestamps"] = ts[:5]
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        assert st.rgb_timestamps_ns.size == 5 and len(list(st.iter_rgb())) == 5
        assert any("aligned on shortest (5)" in n for n in st.notes)


def test_fingerprint_changes_with_file(tmp_path, adapter):
    path = tmp_path / "s.hdf5"
    write_opentouch_scene(path, [clip("demo_1", t=2)])
    (a,) = adapter.discover(tmp_path, {})
    (b,) = adapter.discover(tmp_path, {})
    assert a.fingerprint == b.fingerprint and len(a.fingerprint) == 40
    write_opentouch_scene(path, [clip("demo_1", t=3)])
    (c,) = adapter.discover(tmp_path, {})
    assert c.fingerprint != a.fingerprint


def test_writer_keeps_every_release_key(tmp_path):
    path = tmp_path / "s.hdf5"
    write_opentouch_scene(path, [clip("demo_05", t=10)])
    with h5py.File(path) as f:
        g = f["data/demo_05"]
        assert f["calibration/rgb/T_device_camera"].shape == (4, 4)
        assert f["calibration/rgb/focal_length"].shape == ()
        assert f["calibration/rgb/image_size"].dtype == np.int64
        assert f["calibration/rgb/principal_point"].shape == (2,)
        assert f["transform_slam_to_rgb"].shape == (4, 4)
        assert g["camera_poses"].shape == (10, 4, 4)
        assert g["labels"].dtype.names == ("low_light", "hand_out_of_frame") and g["labels"].shape == (1,)
        assert g["rgb_images_jpeg"].dtype.kind == "O"
        assert np.isnan(g["right_hand_landmarks"][()]).any()
        assert g["right_palm_pos"].shape == g["right_wrist_pos"].shape == (10, 3)
        assert g["right_pressure"].dtype == np.float32 and g["timestamps"].dtype == np.int64


def test_truncated_hdf5_beside_good_files_is_one_failure(tmp_path, adapter):
    write_opentouch_scene(tmp_path / "a_scene.hdf5", [clip("demo_1", t=3), clip("demo_2", t=2)])
    write_opentouch_scene(tmp_path / "b_broken.hdf5", [clip("demo_1", t=5)])
    data = (tmp_path / "b_broken.hdf5").read_bytes()
    (tmp_path / "b_broken.hdf5").write_bytes(data[: len(data) // 2])
    write_opentouch_scene(tmp_path / "c_scene.hdf5", [clip("demo_1", t=4)])
    refs, failures = adapter.discover_all(tmp_path, {})
    assert [r.episode_id for r in refs] == ["ot-a_scene-demo_1", "ot-a_scene-demo_2", "ot-c_scene-demo_1"]
    (f,) = failures
    assert f.file == str(tmp_path / "b_broken.hdf5") and f.episode_id is None and f.frame is None
    assert "HDF5 does not open" in f.message
