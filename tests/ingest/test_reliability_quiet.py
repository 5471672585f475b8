"""The quiet failures of issue 26 item 8: each now one line naming the file, sample or setting.

Before issue 26: the loaders served NaN maps from NaN raw rows; an index row naming shard 4000
raised a bare IndexError; a read-only dataset gave gc/ingest a double traceback from
store/lock.py; a binary .lock gave "'utf-8' codec can't decode" without the file;
`--set sync.max_skew_ms=1e300` an OverflowError; reversed / all-equal video timestamps were
noted only in the record and an int64-max last timestamp accepted; an ingest that changed
nothing after a lost dataset.json left it missing.
"""

from __future__ import annotations

import errno
import io
import tarfile
from pathlib import Path

import numpy as np
import pytest

import htdata
from htdata.cli import main
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from tests.factories import COLOURS, PERIOD, ingest_cli, make_native
from tests.factories.legacy import reseal_index


def native_dataset(tmp_path: Path, *extra) -> Path:
    make_native(tmp_path / "raw")
    assert ingest_cli("--pipeline", f"native={tmp_path / 'raw'}", *extra, tmp_path / "ds") == 0
    return tmp_path / "ds"


def test_nan_raw_rows_are_refused_where_the_map_is_rendered(tmp_path):
    root = native_dataset(tmp_path, "--set", "tactile.maps=raw")
    shard = sorted((root / "shards").glob("*.tar"))[0]
    with tarfile.open(shard) as tf:     # a stranger's dataset: one sample's raw rows made NaN, same size
        info = next(t for t in tf.getmembers() if t.name.endswith("raw_right.npy"))
        rows = np.load(io.BytesIO(tf.extractfile(info).read()))
    buf = io.BytesIO()
    np.save(buf, np.full_like(rows, np.nan))
    assert len(buf.getvalue()) == info.size
    with open(shard, "r+b") as f:
        f.seek(info.offset_data)
        f.write(buf.getvalue())
    key = info.name.split(".")[0]
    with htdata.open(root) as reader:
        with pytest.raises(ValueError, match=rf"{key} \(right\): tactile map holds NaN/Inf"):
            reader.decoded(0)
        assert np.isfinite(reader.decoded(1)["tactile"]["right"]).all()


def test_nan_stored_map_is_refused_when_decoded():
    from htdata.format.tactilecodec import decode_tactile, encode_exr

    bad = np.zeros((224, 224), np.float32)
    bad[5, 5] = np.nan
    with pytest.raises(ValueError, match="ep_x__000003.tactile_right.exr: tactile map holds NaN"):
        decode_tactile(encode_exr(bad, "zip", np.float32), "ep_x__000003.tactile_right.exr")


def test_index_row_naming_a_missing_shard_is_one_line(tmp_path):
    root = native_dataset(tmp_path)
    reseal_index(root, lambda rows: rows["shard"].__setitem__(0, 4000))
    with htdata.open(root) as reader, pytest.raises(ValueError, match="names shard 4000, but version 1 has 1 shards"):
        reader.sample(0)


def lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def test_read_only_dataset_gc_and_ingest_one_line(tmp_path, monkeypatch, capsys):
    root = native_dataset(tmp_path)
    import htdata.fileio as fileio  # the lock is created by fileio.write_bytes_exclusive

    def read_only(path, *a, **kw):
        raise OSError(errno.EROFS, "Read-only file system", str(path))

    monkeypatch.setattr(fileio, "open", read_only, raising=False)
    monkeypatch.setattr(Path, "unlink", lambda self, missing_ok=False: read_only(self))
    capsys.readouterr()
    assert main(["gc", str(root)]) == 2
    err = lines(capsys.readouterr().err)
    assert len(err) == 1 and "Read-only file system" in err[0] and ".lock" in err[0], err
    assert ingest_cli("--pipeline", f"native={tmp_path / 'raw'}", root) == 2
    err = lines(capsys.readouterr().err)
    assert len(err) == 1 and "Read-only file system" in err[0], err


def test_binary_lock_file_is_named(tmp_path, capsys):
    root = native_dataset(tmp_path)
    (root / ".lock").write_bytes(b"\xff\xfe\x00\x81garbage\x00" * 8)
    capsys.readouterr()
    assert main(["gc", str(root)]) == 2
    err = lines(capsys.readouterr().err)
    assert len(err) == 1 and f"{root / '.lock'}: not a writer lock" in err[0], err


@pytest.mark.parametrize("setting", ["sync.max_skew_ms=1e300", "sync.lag=1e300"])
def test_absurd_sync_setting_is_one_line_naming_it(tmp_path, capsys, setting):
    make_native(tmp_path / "raw")
    capsys.readouterr()
    assert ingest_cli("--pipeline", f"native={tmp_path / 'raw'}", "--set", setting, tmp_path / "ds") == 2
    err = lines(capsys.readouterr().err)
    assert len(err) == 1 and setting.split("=")[0].split(".")[1] in err[0] and "Overflow" not in err[0], err


def recording(root: Path, t_video: np.ndarray) -> None:
    t_glove = np.arange(0, 9 * PERIOD, 10_000_000, dtype=np.int64)
    write_native_recording(root, NativeRecording(
        task="grasp_cup", scene="lab", video_storage="jpeg",
        video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * len(t_video), video_timestamps_ns=t_video,
        hands={"right": NativeHand("opentouch_right_16x16", np.full((t_glove.size, 16, 16), 1536.0, np.float32),
                                   t_glove)}))


def test_broken_video_clocks_are_said_on_stderr_and_impossible_gaps_refused(tmp_path, capsys):
    t = np.arange(9, dtype=np.int64) * PERIOD
    recording(tmp_path / "raw" / "rec_reversed", t[::-1].copy())
    recording(tmp_path / "raw" / "rec_equal", np.full(9, PERIOD, np.int64))
    last = t.copy()
    last[-1] = np.iinfo(np.int64).max
    recording(tmp_path / "raw" / "rec_int64max", last)
    recording(tmp_path / "raw" / "rec_fine", t)
    capsys.readouterr()
    assert ingest_cli("--pipeline", f"native={tmp_path / 'raw'}", tmp_path / "ds") == 1
    err = capsys.readouterr().err
    assert "nat-rec_reversed: rgb: timestamps not monotonic" in err
    assert "nat-rec_equal: rgb: all 9 timestamps are equal" in err
    assert "FAILED" in err and "rec_int64max" in err and "no recording has such a gap" in err
    ids = [ep["episode_id"] for ep in htdata.open(tmp_path / "ds").episodes]
    assert "nat-rec_int64max" not in ids and "nat-rec_fine" in ids


def test_unchanged_ingest_restores_a_lost_pointer(tmp_path):
    root = native_dataset(tmp_path)
    before = (root / "dataset.json").read_bytes()
    (root / "dataset.json").unlink()
    assert ingest_cli("--pipeline", f"native={tmp_path / 'raw'}", root) == 0
    assert (root / "dataset.json").read_bytes() == before
