"""TouchAnything-style adapter against fixtures written by htdata.synthetic.formats."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from htdata.errors import EpisodeError
from htdata.source.adapters import get_adapter
from htdata.source.adapters.npzrows import NpzRowError, NpzRows
from htdata.synthetic.formats import TouchAnythingEpisode, write_touchanything_episode, write_touchanything_split

EPOCH = 1_774_000_000.0  # 2026, like the release's trajectory ids
RED = (255, 0, 0)


def grid(t, seed=0):
    """(T,21,21) in [0,1] with NaN at no-sensor cells (top rows + gaps between fingers)."""
    rng = np.random.default_rng(seed)
    g = rng.uniform(0, 1, (t, 21, 21)).astype(np.float32)
    g[:, :2, :] = np.nan
    g[:, :, [0, 4, 8, 12, 16]] = np.nan
    return g


def chest(n, colour=RED):
    for _ in range(n):
        yield np.full((480, 640, 3), colour, dtype=np.uint8)


def episode(t=6, *, video_frames=None, left=True, right=True, seed=0, **kw):
    left_grid = grid(t, seed) if left else None
    right_grid = grid(t, seed + 1)[:, :, ::-1].copy() if right else None  # stored mirrored
    return TouchAnythingEpisode(
        left_grid=left_grid, right_grid=right_grid,
        chest_frames=chest(t if video_frames is None else video_frames),
        ts_epoch_s=EPOCH + np.arange(t) / 30.0, **kw,
    )


def write(root, rel, ep, **kw):
    folder = root / rel
    write_touchanything_episode(folder, ep, wrist_videos=kw.pop("wrist_videos", False), **kw)
    return folder


@pytest.fixture
def adapter():
    return get_adapter("touchanything")


def test_discovery_ids_split_hands(tmp_path, adapter):
    write(tmp_path, "Home/pour_water/20260320_135743_682", episode(4), wrist_videos=True)
    write(tmp_path, "Office/type_keyboard/20260321_101010_001", episode(3, left=False))
    allnan = episode(3)
    allnan.left_grid[:] = np.nan
    write(tmp_path, "Retail/scan_item/20260322_090000_000", allnan)
    write_touchanything_split(tmp_path, {
        "train": ["/data/ta/Home/pour_water/20260320_135743_682"],
        "test_unseen": ["Office/type_keyboard/20260321_101010_001"],
    })
    refs = adapter.discover(tmp_path, {})
    assert [r.episode_id for r in refs] == [
        "ta-Home-pour_water-20260320_135743_682",
        "ta-Office-type_keyboard-20260321_101010_001",
        "ta-Retail-scan_item-20260322_090000_000",
    ]
    home, office, retail = refs
    assert (home.scene, home.task, home.hands, home.est_frames) == ("Home", "pour_water", ("left", "right"), 4)
    assert home.layouts == {"left": "touchanything_left_21x21", "right": "touchanything_right_21x21"}
    assert home.extra["source_split"] == "train" and office.extra["source_split"] == "test_unseen"
    assert "source_split" not in retail.extra
    assert office.hands == ("right",)
    assert retail.hands == ("right",) and retail.extra["hands_excluded"] == {"left": "all-NaN"}
    assert (tmp_path / "Home/pour_water/20260320_135743_682/left.mp4").stat().st_size > 0


def test_rgb_streamed_red_and_timestamps_on_tactile_clock(tmp_path, adapter):
    write(tmp_path, "Home/t/a", episode(5))
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        tact = st.tactile_timestamps_ns["left"]
        expected = np.round((EPOCH + np.arange(5) / 30.0) * 1e9).astype(np.int64)
        assert np.abs(tact - expected).max() < 1_000  # float64 epoch seconds keep ~0.2 us
        assert st.rgb_timestamps_ns[0] == tact[0]
        assert np.abs(st.rgb_timestamps_ns - tact).max() < 1_000_000  # 30 fps video pts vs 30 Hz rows
        out = list(st.iter_rgb())
        assert st.notes == []
    assert [i for i, _ in out] == list(range(5))
    for _, img in out:
        assert img.shape == (480, 640, 3) and img.dtype == np.uint8
        mean = img.reshape(-1, 3).mean(0)
        assert mean[0] > 230 and mean[1] < 25 and mean[2] < 25


@pytest.mark.parametrize("compress", [True, False])
def test_tactile_rows_equal_written_nan_and_mirroring_kept(tmp_path, adapter, compress):
    ep = episode(7, seed=3, npz_scalars={})  # no scalar keys at all: never required
    left, right = ep.left_grid.copy(), ep.right_grid.copy()
    write(tmp_path, "Workbench/drill/x1", ep, compress_npz=compress)
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        for hand, arr in (("left", left), ("right", right)):
            got = st.read_tactile(hand, np.arange(7))
            assert got.dtype == np.float32
            np.testing.assert_array_equal(got, arr)  # NaN positions equal too; right stays mirrored
        np.testing.assert_array_equal(st.read_tactile("right", np.array([6, 1, 1, 4])), right[[6, 1, 1, 4]])
        np.testing.assert_array_equal(st.read_tactile("left", np.array([2, 3])), left[[2, 3]])
        np.testing.assert_array_equal(st.read_tactile("left", np.array([0])), left[[0]])  # backwards: reopen


def test_npz_rows_chunked_forward_reads(tmp_path):
    arr = np.arange(50 * 3 * 2, dtype=np.float64).reshape(50, 3, 2)
    np.savez_compressed(tmp_path / "a.npz", x=arr, s=np.float32(1))
    rows = NpzRows(tmp_path / "a.npz", "x", chunk_rows=4)
    try:
        assert rows.shape == (50, 3, 2) and rows.num_rows == 50
        np.testing.assert_array_equal(rows.read([3, 17, 18, 40]), arr[[3, 17, 18, 40]])
        np.testing.assert_array_equal(rows.read([45, 41, 49]), arr[[45, 41, 49]])
        np.testing.assert_array_equal(rows.read([1]), arr[[1]])
        np.testing.assert_array_equal(rows.read_all(), arr)
        with pytest.raises(NpzRowError, match="out of range"):
            rows.read([50])
    finally:
        rows.close()
    with pytest.raises(NpzRowError, match="has no array 'y'"):
        NpzRows(tmp_path / "a.npz", "y")


def _npy_bytes_claiming(rows_claimed, arr):
    """A .npy member whose header promises more rows than its data holds."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False,
                                                "shape": (rows_claimed,) + arr.shape[1:]})
    buf.write(arr.astype("<f4").tobytes())
    return buf.getvalue()


def test_member_declaring_more_rows_than_it_holds_is_refused_before_reading(tmp_path, adapter):
    # Declared sizes are checked against the bytes present (issue #11): a member whose header claims
    # 8 rows but holds 4 is refused at discovery, naming the file, the episode and both sizes.
    folder = write(tmp_path, "Home/t/a", episode(8))
    good = grid(4)
    with zipfile.ZipFile(folder / "pressure_grids.npz", "w") as z:
        z.writestr("left_pressure_grid.npy", _npy_bytes_claiming(8, good))
    with pytest.raises(EpisodeError) as err:
        adapter.discover(tmp_path, {})
    msg = str(err.value)
    assert "pressure_grids.npz [ta-Home-t-a]" in msg and "declares shape (8, 21, 21)" in msg
    assert f"holds {good.nbytes} bytes" in msg


def test_truncated_npz_file_fails_discovery_with_names(tmp_path, adapter):
    folder = write(tmp_path, "Home/t/a", episode(4))
    npz = folder / "pressure_grids.npz"
    npz.write_bytes(npz.read_bytes()[:200])
    with pytest.raises(EpisodeError, match=r"pressure_grids.npz \[ta-Home-t-a\]: not a readable npz"):
        adapter.discover(tmp_path, {})


@pytest.mark.parametrize("video_frames,expect", [(8, "chest.mp4 has 2 frames more than tactile"),
                                                 (5, "tactile has 1 frame more than chest.mp4")])
def test_video_npz_length_mismatch_noted(tmp_path, adapter, video_frames, expect):
    write(tmp_path, "Home/t/a", episode(6, video_frames=video_frames))
    (ref,) = adapter.discover(tmp_path, {})
    n = min(6, video_frames)
    with adapter.open(ref, {}) as st:
        assert any(expect in note and f"aligned on shortest ({n})" in note for note in st.notes)
        assert st.rgb_timestamps_ns.size == n and st.tactile_timestamps_ns["right"].size == n
        assert len(list(st.iter_rgb())) == n


def test_missing_jq_uses_frame_index_clock(tmp_path, adapter):
    folder = write(tmp_path, "Home/t/a", episode(4))
    (folder / "jq_pressure.json").unlink()
    (ref,) = adapter.discover(tmp_path, {})
    with adapter.open(ref, {}) as st:
        np.testing.assert_array_equal(st.tactile_timestamps_ns["left"], np.arange(4) * 1_000_000_000 // 30)
        assert any("frame_index / 30 s" in n for n in st.notes)


def test_bad_jq_line_names_line(tmp_path, adapter):
    folder = write(tmp_path, "Home/t/a", episode(4))
    lines = (folder / "jq_pressure.json").read_text().splitlines()
    lines[2] = '{"frame_index": 2, "sensor_left": []}'
    (folder / "jq_pressure.json").write_text("\n".join(lines) + "\n")
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match=r"jq_pressure.json \[ta-Home-t-a\] frame 2: bad jq_pressure.json line 3"):
        adapter.open(ref, {})


def test_undecodable_video(tmp_path, adapter):
    folder = write(tmp_path, "Home/t/a", episode(4))
    video = folder / "chest.mp4"
    video.write_bytes(video.read_bytes()[:300])
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match=r"chest.mp4 \[ta-Home-t-a\]: video does not open"):
        adapter.open(ref, {})


def test_zero_frame_video(tmp_path, adapter):
    write(tmp_path, "Home/t/a", episode(3, video_frames=0))
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match=r"chest.mp4 \[ta-Home-t-a\]: video has zero frames"):
        adapter.open(ref, {})


def test_zero_rows_and_wrong_grid_shape(tmp_path, adapter):
    write(tmp_path, "Home/t/empty", episode(0, video_frames=1))
    with pytest.raises(EpisodeError, match=r"\[ta-Home-t-empty\]: no usable tactile grid .*zero rows"):
        adapter.discover(tmp_path, {})
    folder = tmp_path / "Home/t/empty"
    np.savez(folder / "pressure_grids.npz", left_pressure_grid=np.zeros((1, 16, 16), np.float32))
    (ref,) = adapter.discover(tmp_path, {})
    with pytest.raises(EpisodeError, match=r"\(1, 16, 16\) does not match layout 'touchanything_left_21x21'"):
        adapter.open(ref, {})


def test_folder_not_three_levels_deep(tmp_path, adapter):
    write(tmp_path, "flat", episode(2))
    with pytest.raises(EpisodeError, match="Scene}/{task}/{trajectory}"):
        adapter.discover(tmp_path, {})


def zero_video_packet(video, index):
    """Overwrite the payload of the index-th video packet (decode order) with zeros; return its pts rank."""
    import av

    with av.open(str(video)) as c:
        packets = [(p.pos, p.size, p.pts) for p in c.demux(c.streams.video[0]) if p.size]
    pos, size, pts = packets[index]
    data = bytearray(video.read_bytes())
    data[pos:pos + size] = bytes(size)
    video.write_bytes(bytes(data))
    return int(np.searchsorted(np.sort([p[2] for p in packets]), pts))


def test_corrupt_packet_mid_video_fails_the_episode_at_that_frame(tmp_path, adapter):
    """Policy: a mid-video corrupt frame fails the whole episode (EpisodeError naming the frame);
    frames before it are decoded but the ingest never keeps half an episode."""
    rng = np.random.default_rng(3)
    noise = [rng.integers(0, 256, (480, 640, 3), dtype=np.uint8) for _ in range(12)]  # every packet carries data
    ep = episode(12)
    ep.chest_frames = noise
    folder = write(tmp_path, "Home/t/a", ep)
    frame = zero_video_packet(folder / "chest.mp4", 8)
    assert frame == 8
    (ref,) = adapter.discover(tmp_path, {})
    delivered = []
    with adapter.open(ref, {}) as st:
        assert st.rgb_timestamps_ns.size == 12           # the container still lists every packet
        with pytest.raises(EpisodeError) as err:
            for i, rgb in st.iter_rgb():
                delivered.append(i)
    e = err.value
    assert (e.episode_id, e.frame) == ("ta-Home-t-a", 8) and e.file.endswith("chest.mp4")
    assert "corrupt packet at frame 8" in e.message
    assert delivered == list(range(len(delivered))) and len(delivered) <= 8
    last = len(delivered) - 1   # the frames that did come out are the recorded ones, in order
    own = np.abs(rgb.astype(int) - noise[last]).mean()
    assert own < 0.75 * min(np.abs(rgb.astype(int) - noise[j]).mean() for j in range(12) if j != last)
