"""`export lerobot --tactile-window K`: every glove row the dataset served, once, at its own time.

The reference is the reader's full-rate stream (htdata.read.rawstream.episode_stream), not the
export's own bookkeeping: concatenating each frame's masked window rows must give that stream
back row for row, with --fps resampling (skipped and repeated frames) too.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from htdata.cli import main as cli  # noqa: E402
from htdata.export.lerobot_window import window_keys  # noqa: E402
from htdata.read.rawstream import episode_stream  # noqa: E402
from htdata.read.reader import DatasetReader  # noqa: E402
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording  # noqa: E402
from tests.factories import PERIOD, ingest_cli, small_pipeline  # noqa: E402

FRAMES = 12


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Video at 30 fps, a right glove at 100 Hz (3-4 rows per frame), a left glove at 200 Hz from frame 4
    (frames 0-3 are stored RGB-only; their right rows are kept in frame 4: 17 rows there)."""
    tmp = tmp_path_factory.mktemp("window")
    rng = np.random.default_rng(11)
    t_video = np.arange(FRAMES, dtype=np.int64) * PERIOD
    t_right = np.arange(0, FRAMES * PERIOD, 10_000_000, dtype=np.int64)
    t_left = np.arange(4 * PERIOD, FRAMES * PERIOD, 5_000_000, dtype=np.int64)
    frames = [np.full((48, 64, 3), 10 * k, np.uint8) for k in range(FRAMES)]
    write_native_recording(tmp / "raw" / "rec_a", NativeRecording(
        task="pour", scene="lab", video_storage="jpeg", video_frames=frames, video_timestamps_ns=t_video,
        hands={"right": NativeHand("opentouch_right_16x16", rng.uniform(0, 3072, (t_right.size, 16, 16))
                                   .astype(np.float32), t_right),
               "left": NativeHand("touchanything_left_21x21", rng.uniform(0, 1, (t_left.size, 21, 21))
                                  .astype(np.float32), t_left)}))
    out = tmp / "ds"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp, 'native')}={tmp / 'raw'}", out) == 0
    return out


def exported(root):
    info = json.loads((root / "meta/info.json").read_text())
    data = pa.concat_tables([pq.read_table(p) for p in sorted((root / "data").rglob("*.parquet"))]).to_pydict()
    return info, data, json.loads((root / "meta/stats.json").read_text())


@pytest.mark.parametrize("fps", [None, 15, 45])
def test_every_served_row_is_in_exactly_one_window(dataset, tmp_path, fps):
    out = tmp_path / "lr"
    args = ["export", "lerobot", str(dataset), str(out), "--quiet", "--tactile-window", "24"]
    assert cli(args + (["--fps", str(fps)] if fps else [])) == 0
    info, data, stats = exported(out)
    reader = DatasetReader(dataset)
    eid = reader.episodes[0]["episode_id"]
    t0 = None
    for hand in ("right", "left"):
        raw_key = next(k for k in info["features"] if k.startswith(f"observation.tactile.{hand}.raw"))
        window, mask, dt = window_keys(raw_key)
        k, rows, cols = info["features"][window]["info"]["window"]
        assert k == 24 and info["features"][window]["shape"] == [k * rows * cols]
        values = np.asarray(data[window], np.float32).reshape(-1, k, rows, cols)
        m = np.asarray(data[mask], bool)
        got = values[m]                                          # oldest first within a frame, frames in order
        want = episode_stream(reader, eid, hand)
        assert got.shape == want.rows.shape, (hand, got.shape, want.rows.shape)
        assert np.array_equal(got, np.where(np.isfinite(want.rows), want.rows, 0).astype(np.float32))
        # each row's time: the frame's source time + dt (the export's timestamps sit on its own grid)
        src = np.asarray(data["htdata.frame_index"])
        t_frame = np.array([json.loads(reader.sample(int(f), ("json",))["json"])["t_rgb_ns"] for f in src])
        t_rows = (t_frame[:, None] + np.asarray(data[dt], np.float64) * 1e9)[m]
        assert np.allclose(t_rows, want.t_ns, atol=2_000), hand    # float32 seconds: ~1 us
        assert (values[~m] == 0).all()
        t0 = t_frame[0]
        assert len(stats[window]["mean"]) == k * rows * cols and stats[window]["count"] == [int(m.sum())]
    assert t0 is not None


def test_a_window_too_small_names_the_frame_and_the_k_needed(dataset, tmp_path, capsys):
    out = tmp_path / "small"
    assert cli(["export", "lerobot", str(dataset), str(out), "--quiet", "--tactile-window", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "glove rows were recorded since the previous frame" in err
    assert "pass --tactile-window" in err and "frame " in err and not out.exists()
    assert cli(["export", "lerobot", str(dataset), str(out), "--quiet", "--tactile-window", "0"]) == 2
    assert "--tactile-window must be a whole number >= 1" in capsys.readouterr().err


def test_without_a_window_the_export_is_unchanged(dataset, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert cli(["export", "lerobot", str(dataset), str(a), "--quiet"]) == 0
    assert cli(["export", "lerobot", str(dataset), str(b), "--quiet", "--tactile-window", "24"]) == 0
    info_a, data_a, _ = exported(a)
    info_b, data_b, _ = exported(b)
    assert not any(".window" in key for key in info_a["features"])
    assert all(data_a[key] == data_b[key] for key in data_a)              # the window only adds columns
