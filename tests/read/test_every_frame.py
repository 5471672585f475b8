"""Every recorded frame is kept: RGB frames without tactile (RGB-only samples), glove-only recordings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from htdata.cli import main as cli
from htdata.format.table import RGB_MEMBER, raw_member, tactile_member
from htdata.read.itemoptions import ItemOptions
from htdata.read.reader import DatasetReader
from htdata.read.torchdata import TactileFrameDataset, TactileStream, TactileWindowDataset
from htdata.store.manifest import load_episodes
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from tests.factories import COLOURS, PERIOD, ingest_cli, small_pipeline

LAYOUT = "opentouch_right_16x16"


def recording(folder: Path, frames: int = 12, glove_start: int = 0, video: str = "jpeg") -> int:
    """30 Hz video; a 100 Hz glove starting at video frame `glove_start`; returns the glove's row count."""
    t_video = np.arange(frames, dtype=np.int64) * PERIOD
    t_glove = np.arange(glove_start * PERIOD, frames * PERIOD, 10_000_000, dtype=np.int64)
    values = np.random.default_rng(1).uniform(0, 3072, size=(t_glove.size, 16, 16)).astype(np.float32)
    write_native_recording(folder, NativeRecording(
        task="grasp", scene="lab", video_storage=video,
        video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * frames, video_timestamps_ns=t_video,
        hands={"right": NativeHand(LAYOUT, values, t_glove)}))
    return t_glove.size


def ingest(tmp_path: Path, src: Path, extra: str = "") -> Path:
    pipeline = small_pipeline(tmp_path, "native")
    if extra:
        pipeline.write_text(pipeline.read_text().replace('interpolation = "area"', f'interpolation = "area"\n{extra}'))
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", f"{pipeline}={src}", out) == 0
    return out


def metas(root: Path) -> list[dict]:
    reader = DatasetReader(root)
    return [json.loads(reader.sample(i)["json"]) for i in range(len(reader))]


def test_rgb_frames_before_the_glove_starts_are_rgb_only_samples(tmp_path):
    recording(tmp_path / "raw" / "rec_late", glove_start=4)
    out = ingest(tmp_path, tmp_path / "raw")
    ep = load_episodes(out)[0]
    m = metas(out)
    assert ep["num_frames"] == 12 and [x["source_frame"] for x in m] == list(range(12))
    assert [x.get("rgb_only") for x in m[:4]] == ["tactile_out_of_range:right"] * 4
    assert all("rgb_only" not in x and x["hands"]["right"] for x in m[4:])
    assert ep["rgb_only_frames"] == {"tactile_out_of_range:right": 4} and ep["stats"]["frames_kept"] == 8
    reader = DatasetReader(out)
    for i in range(4):
        members = reader.sample(i)
        assert RGB_MEMBER in members and tactile_member("right") not in members and raw_member("right") not in members
    assert cli(["validate", str(out), "--deep"]) == 0
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert report["rgb_only_samples"] == {"tactile_out_of_range:right": 4}
    # loaders: paired frames only by default; windows never reach into the RGB-only head
    assert sorted(int(i) for i, _ in TactileFrameDataset(out).items) == list(range(4, 12))
    windows = TactileWindowDataset(out, window=3)
    assert sorted(int(e) for e, _ in windows.items) == list(range(6, 12))
    assert len(list(TactileStream(out))) == 8


def test_keep_unpaired_false_drops_them_as_before(tmp_path):
    recording(tmp_path / "raw" / "rec_late", glove_start=4)
    out = ingest(tmp_path, tmp_path / "raw", extra="keep_unpaired = false")
    ep = load_episodes(out)[0]
    assert ep["num_frames"] == 8 and "rgb_only_frames" not in ep
    assert ep["dropped_frames"] == {"tactile_out_of_range:right": 4}


def test_a_glove_only_recording_ingests_as_tactile_only_samples(tmp_path):
    rows = recording(tmp_path / "raw" / "rec_glove", video="none")
    assert not (tmp_path / "raw" / "rec_glove" / "ego_timestamps.npy").exists()
    out = ingest(tmp_path, tmp_path / "raw")
    ep = load_episodes(out)[0]
    assert ep["tactile_only"] is True and ep["num_frames"] == rows      # one sample per glove row
    assert ep["fps"] == pytest.approx(100.0)
    m = metas(out)
    assert all(x["tactile_only"] and x["hands"]["right"] for x in m)
    reader = DatasetReader(out)
    assert all(RGB_MEMBER not in reader.sample(i) for i in range(len(reader)))
    assert cli(["validate", str(out), "--deep"]) == 0
    with pytest.raises(ValueError, match='glove-only dataset.*frames="tactile"'):   # says why, not length 0
        TactileFrameDataset(out)
    tactile = TactileFrameDataset(out, options=ItemOptions(frames="tactile"))   # e.g. stage-1 tokeniser data
    assert len(tactile) == rows
    item = tactile[0]
    assert not bool(item["has_rgb"]) and int(item["rgb"].max()) == 0 and item["tactile"].shape == (1, 224, 224)
    assert len(list(TactileStream(out, options=ItemOptions(frames="tactile")))) == rows
    with pytest.raises(ValueError, match="glove-only dataset"):
        len(TactileStream(out))


def test_frames_option_is_checked(tmp_path):
    recording(tmp_path / "raw" / "rec", frames=4)
    out = ingest(tmp_path, tmp_path / "raw")
    with pytest.raises(ValueError, match="frames must be one of"):
        TactileFrameDataset(out, options=ItemOptions(frames="all"))


def test_preview_stats_and_card_read_rgb_only_and_tactile_only_samples(tmp_path):
    recording(tmp_path / "raw" / "rec_late", glove_start=4)
    recording(tmp_path / "raw" / "rec_glove", video="none")
    out = ingest(tmp_path, tmp_path / "raw")
    for episode in ("nat-rec_late", "nat-rec_glove"):
        assert cli(["preview", str(out), str(tmp_path / f"{episode}.png"), "--episode", episode]) == 0
    assert cli(["stats", str(out), "--json"]) == 0
    assert cli(["card", str(out), str(tmp_path / "card.html")]) == 0
    assert cli(["validate", str(out), "--deep"]) == 0


def test_rgb_frame_with_a_duplicate_timestamp_stays_dropped_and_counted(tmp_path):
    folder = tmp_path / "raw" / "rec_dup"
    recording(folder, frames=10)
    ts = np.load(folder / "ego_timestamps.npy")
    ts[5] = ts[4]                                   # the camera stamped two frames alike
    np.save(folder / "ego_timestamps.npy", ts)
    out = ingest(tmp_path, tmp_path / "raw")
    m = metas(out)                                  # a second frame at one time cannot be ordered
    assert [x["source_frame"] for x in m] == [0, 1, 2, 3, 4, 6, 7, 8, 9]
    assert load_episodes(out)[0]["dropped_frames"] == {"duplicate_timestamp": 1}
    assert cli(["validate", str(out), "--deep"]) == 0


def test_renormalise_skips_rgb_only_samples(tmp_path):
    recording(tmp_path / "raw" / "rec_late", glove_start=4)
    out = ingest(tmp_path, tmp_path / "raw")
    assert cli(["renormalise", str(out), "--pipeline", "native", "--force"]) == 0
    a, b = DatasetReader(out, version=1), DatasetReader(out, version=2)
    assert all(a.sample(i) == b.sample(i) for i in range(len(a)))     # byte for byte, RGB-only ones too
    setting = ["--set", f"normalise.{LAYOUT}.baseline=rest_window", "--set", f"normalise.{LAYOUT}.noise_k=3"]
    assert cli(["renormalise", str(out), "--pipeline", "native", *setting]) == 0
    assert cli(["validate", str(out), "--deep"]) == 0
    ep = load_episodes(out)[0]
    assert ep["stats"]["frames_kept"] == 8 and 0 <= ep["stats"]["mean_contact"]["right"] <= 1   # over the 8 maps
