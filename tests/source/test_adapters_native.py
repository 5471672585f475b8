"""htdata-native adapter against fixtures written by htdata.synthetic.formats."""

from __future__ import annotations

import json

import numpy as np
import pytest

from htdata.errors import EpisodeError
from htdata.source.adapters import ADAPTERS, get_adapter
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording

VIDEO_T0 = 5_000_000_000
FRAME_NS = 33_333_333
RED = (255, 0, 0)


def video(n, colour=RED, size=(48, 64)):
    for _ in range(n):
        yield np.full((*size, 3), colour, dtype=np.uint8)


def hand(layout, m, period_ns, offset_ns, seed=0, grid=(16, 16)):
    rng = np.random.default_rng(seed)
    return NativeHand(layout=layout, values=rng.uniform(0, 3072, (m, *grid)).astype(np.float32),
                      timestamps_ns=np.arange(m, dtype=np.int64) * period_ns, clock_offset_ns=offset_ns)


def recording(n_video=9, *, storage="mp4", hands=None, n_ts=None):
    return NativeRecording(
        task="pour", scene="lab", operator="op1", notes="fixture",
        video_frames=video(n_video), video_storage=storage,
        video_timestamps_ns=VIDEO_T0 + np.arange(n_video if n_ts is None else n_ts, dtype=np.int64) * FRAME_NS,
        hands=hands or {"right": hand("opentouch_right_16x16", 30, 10_000_000, VIDEO_T0 + 2_000_000)},
    )


@pytest.fixture
def adapter():
    return get_adapter("native")


def test_registry():
    assert set(ADAPTERS) == {"opentouch", "touchanything", "native"}
    assert get_adapter("native").name == "native"
    with pytest.raises(ValueError, match="unknown adapter 'hdf5'"):
        get_adapter("hdf5")


def test_100hz_tactile_vs_30hz_video_with_clock_offsets(tmp_path, adapter):
    right = hand("opentouch_right_16x16", 30, 10_000_000, VIDEO_T0 + 2_000_000, seed=1)      # 100 Hz
    left = hand("touchanything_left_21x21", 15, 20_000_000, VIDEO_T0 - 7_000_000, seed=2, grid=(21, 21))  # 50 Hz
    left.values[:, 0, :] = np.nan
    write_native_recording(tmp_path / "session 01", recording(9, hands={"right": right, "left": left}))
    (ref,) = adapter.discover(tmp_path, {})
    assert ref.episode_id == "nat-session_01" and (ref.task, ref.scene) == ("pour", "lab")
    assert ref.hands == ("left", "right") and ref.est_frames == 9
    assert ref.layouts == {"left": "touchanything_left_21x21", "right": "opentouch_right_16x16"}
    assert ref.extra["clock_offset_ns"] == {"left": VIDEO_T0 - 7_000_000, "right": VIDEO_T0 + 2_000_000}
    with adapter.open(ref, {}) as st:
        np.testing.assert_array_equal(st.rgb_timestamps_ns, VIDEO_T0 + np.arange(9) * FRAME_NS)
        np.testing.assert_array_equal(st.tactile_timestamps_ns["right"], right.timestamps_ns + right.clock_offset_ns)
        np.testing.assert_array_equal(st.tactile_timestamps_ns["left"], left.timestamps_ns + left.clock_offset_ns)
        assert st.tactile_timestamps_ns["right"].size == 30 and st.tactile_timestamps_ns["left"].size == 15
        np.testing.assert_array_equal(st.read_tactile("right", np.arange(0, 30, 3)), right.values[::3])
        np.testing.assert_array_equal(st.read_tactile("left", np.arange(15)), left.values)  # NaN kept
        frames = list(st.iter_rgb())
        assert st.notes == []
    assert len(frames) == 9
    for _, img in frames:
        assert img.shape == (48, 64, 3)
        assert img[..., 0].mean() > 230 and img[..., 1:].mean() < 25


def test_jpeg_frames_dir_red_stays_red(tmp_path, adapter):
    write_native_recording(tmp_path / "r", recording(4, storage="jpeg"))
    doc = json.loads((tmp_path / "r/recording.json").read_text())
    assert doc["video"] == {"frames_dir": "frames", "timestamps": "ego_timestamps.npy"}
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        out = list(st.iter_rgb())
    assert [i for i, _ in out] == [0, 1, 2, 3]
    assert all(np.abs(img.reshape(-1, 3).mean(0) - RED).max() < 4 for _, img in out)


def test_corrupt_jpeg_in_frames_dir(tmp_path, adapter):
    write_native_recording(tmp_path / "r", recording(4, storage="jpeg"))
    (tmp_path / "r/frames/000002.jpg").write_bytes(b"garbage")
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        it = st.iter_rgb()
        next(it), next(it)
        with pytest.raises(EpisodeError, match=r"000002.jpg \[nat-r\] frame 2: JPEG does not decode"):
            next(it)


def test_timestamp_count_mismatch_noted(tmp_path, adapter):
    write_native_recording(tmp_path / "r", recording(6, n_ts=8))
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        assert st.rgb_timestamps_ns.size == 6
        assert any("ego_timestamps.npy has 2 frames more than video: aligned on shortest (6)" in n for n in st.notes)
        assert len(list(st.iter_rgb())) == 6


def test_a_timestamp_count_far_from_the_video_is_a_printed_warning(tmp_path, adapter, capsys):
    """Issue 44 weak edge: 100x more stamps than frames was recorded as a note but never printed."""
    from tests.factories import ingest_cli

    write_native_recording(tmp_path / "raw" / "r", recording(6, n_ts=600))
    (ref,) = adapter.discover(tmp_path / "raw", {})
    with adapter.open(ref, {}) as st:
        assert any(n.startswith("warning: ego_timestamps.npy has 594 frames more than video") and "100x apart" in n
                   for n in st.notes), st.notes
    assert ingest_cli("--pipeline", "native", tmp_path / "raw", tmp_path / "ds") == 0
    assert "100x apart, so they may not describe the same recording" in capsys.readouterr().err


def test_schema_violation_names_the_file(tmp_path, adapter):
    write_native_recording(tmp_path / "r", recording(2))
    path = tmp_path / "r/recording.json"
    doc = json.loads(path.read_text())
    doc["format_version"] = 2
    path.write_text(json.dumps(doc))
    with pytest.raises(EpisodeError, match=r"r/recording.json \[nat-r\]: schema violation.*format_version"):
        adapter.discover(tmp_path, {})
    path.write_text("{not json")
    with pytest.raises(EpisodeError, match="recording.json does not parse"):
        adapter.discover(tmp_path, {})


def test_path_escape_and_missing_files_rejected(tmp_path, adapter):
    write_native_recording(tmp_path / "r", recording(2))
    path = tmp_path / "r/recording.json"
    doc = json.loads(path.read_text())
    doc["hands"]["right"]["file"] = "../../etc/passwd"
    path.write_text(json.dumps(doc))
    with pytest.raises(EpisodeError, match="schema violation"):
        adapter.discover(tmp_path, {})
    doc["hands"]["right"]["file"] = "missing.npz"
    path.write_text(json.dumps(doc))
    with pytest.raises(EpisodeError, match="missing files .*missing.npz"):
        adapter.discover(tmp_path, {})


def test_wrong_grid_shape_and_unknown_layout(tmp_path, adapter):
    bad = hand("touchanything_left_21x21", 5, 10_000_000, 0)  # 16x16 values under a 21x21 layout
    write_native_recording(tmp_path / "shape", recording(3, hands={"left": bad}))
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match=r"tactile_left.npz \[nat-shape\]: left tactile grid shape \(5, 16, 16\)"):
        adapter.open(ref, {})
    (tmp_path / "shape/recording.json").unlink()
    write_native_recording(tmp_path / "layout", recording(3, hands={"right": hand("no_such_glove", 5, 10_000_000, 0)}))
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match="layout 'no_such_glove' cannot be loaded"):
        adapter.open(ref, {})


def test_zero_frames(tmp_path, adapter):
    write_native_recording(tmp_path / "novideo", recording(0))
    write_native_recording(tmp_path / "notactile", recording(2, hands={"right": hand("opentouch_right_16x16", 0, 1, 0)}))
    refs = {r.episode_id: r for r in adapter.discover(tmp_path, {})}
    with pytest.raises(EpisodeError, match=r"ego.mp4 \[nat-novideo\]: video has zero frames"):
        adapter.open(refs["nat-novideo"], {})
    with pytest.raises(EpisodeError, match=r"tactile_right.npz \[nat-notactile\]: right tactile stream has zero frames"):
        adapter.open(refs["nat-notactile"], {})


def test_truncated_tactile_npz(tmp_path, adapter):
    write_native_recording(tmp_path / "r", recording(2))
    npz = tmp_path / "r/tactile_right.npz"
    npz.write_bytes(npz.read_bytes()[:1000])
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match=r"tactile_right.npz \[nat-r\]: not a readable npz"):
        adapter.open(ref, {})


def test_discover_all_keeps_good_recordings_beside_bad_and_duplicate_ones(tmp_path, adapter):
    write_native_recording(tmp_path / "a" / "r1", recording(3))
    write_native_recording(tmp_path / "b" / "r1", recording(3))          # same folder name: same episode id
    write_native_recording(tmp_path / "c" / "r2", recording(3))
    (tmp_path / "c" / "r2" / "recording.json").write_text("{truncated")
    write_native_recording(tmp_path / "d" / "r3", recording(4))
    refs, failures = adapter.discover_all(tmp_path, {})
    assert [r.episode_id for r in refs] == ["nat-r1", "nat-r3"]
    assert refs[0].source_ref == str(tmp_path / "a" / "r1")             # the first file keeps the id
    assert [(f.file, f.episode_id) for f in failures] == [
        (str(tmp_path / "b" / "r1" / "recording.json"), "nat-r1"),
        (str(tmp_path / "c" / "r2" / "recording.json"), "nat-r2")]
    assert "also produced by" in failures[0].message and "does not parse" in failures[1].message
    with pytest.raises(EpisodeError, match="also produced by"):      # the strict form raises the first one
        adapter.discover(tmp_path, {})


def test_discover_all_names_the_file_of_an_unexpected_error(tmp_path, adapter, monkeypatch):
    from htdata.source.adapters.native import NativeAdapter

    write_native_recording(tmp_path / "r1", recording(3))
    write_native_recording(tmp_path / "r2", recording(3))
    original = NativeAdapter.discover_file

    def flaky(self, path, root, params, context):
        if path.parent.name == "r1":
            raise KeyError("hands")
        return original(self, path, root, params, context)

    monkeypatch.setattr(NativeAdapter, "discover_file", flaky)
    refs, failures = adapter.discover_all(tmp_path, {})
    assert [r.episode_id for r in refs] == ["nat-r2"]
    (f,) = failures
    assert f.file == str(tmp_path / "r1" / "recording.json") and f.episode_id is None
    assert str(f).endswith("r1/recording.json: KeyError: 'hands'")
