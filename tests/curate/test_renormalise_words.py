"""`htdata renormalise` and `htdata export --maps` on a raw-count glove say what the ingest says (issue 34 item 6)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from htdata.cli import main as cli
from htdata.store.manifest import load_episodes
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from htdata.synthetic.rawglove import LAYOUT_IDS, layout_doc
from tests.factories import PERIOD, ingest_cli

LAYOUT = LAYOUT_IDS["right"]


def knit_recording(folder: Path, frames: int = 90) -> None:
    """Glove only: counts resting ~557 with per-cell offsets and noise, a press of 60-200 counts mid-clip."""
    rng = np.random.default_rng(7)
    doc = layout_doc("right")
    grid = tuple(doc["grid"])
    rest = 557 + rng.normal(0, 20, grid)
    values = rest + rng.normal(0, 0.7, (frames, *grid))
    values[30:60, 10:16, 4:10] += rng.uniform(60, 200, (30, 6, 6))
    (folder / "glove").mkdir(parents=True)
    (folder / "glove" / f"{LAYOUT}.json").write_text(json.dumps(doc))
    write_native_recording(folder, NativeRecording(
        task="squeeze", scene="lab", video_storage="none", video_frames=[], video_timestamps_ns=np.zeros(0, np.int64),
        hands={"right": NativeHand(f"glove/{LAYOUT}.json", np.round(values).astype(np.float32),
                                   np.arange(frames, dtype=np.int64) * PERIOD, dtype="float16")}))


@pytest.fixture
def knit_dataset(tmp_path):
    knit_recording(tmp_path / "raw" / "rec")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", tmp_path / "raw", out) == 0
    return out


def test_renormalise_to_baseline_none_warns_like_the_ingest(knit_dataset, capsys):
    capsys.readouterr()
    setting = ["--set", f"normalise.{LAYOUT}.baseline=none"]
    assert cli(["renormalise", str(knit_dataset), "--pipeline", "native", "--dry-run", *setting]) == 0
    err = capsys.readouterr().err
    assert err.count("rest level") == 1 and 'baseline = "none"' in err and "nat-rec" in err, err
    assert cli(["renormalise", str(knit_dataset), "--pipeline", "native", *setting]) == 0
    assert capsys.readouterr().err.count("rest level") == 1
    notes = load_episodes(knit_dataset)[0]["notes"]
    assert any("rest level" in n and 'baseline = "none"' in n for n in notes), notes


def test_export_maps_says_when_the_videos_are_faint_and_applies_the_gain(knit_dataset, tmp_path, capsys):
    pytest.importorskip("pyarrow")
    capsys.readouterr()
    assert cli(["export", "lerobot", str(knit_dataset), str(tmp_path / "lr"), "--maps", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "map video is faint" in err and "--maps-gain" in err, err
    gain = float(err.split("--maps-gain ")[2].split()[0])
    assert gain > 1
    assert cli(["export", "lerobot", str(knit_dataset), str(tmp_path / "lr2"), "--maps", "--quiet",
                "--maps-gain", str(gain)]) == 0
    assert "faint" not in capsys.readouterr().err
    info = json.loads((tmp_path / "lr2" / "meta" / "info.json").read_text())
    assert f"x {gain:g}" in info["features"]["observation.tactile.right.map"]["info"]["htdata.grey_level"]
    assert cli(["export", "lerobot", str(knit_dataset), str(tmp_path / "lr3"), "--maps", "--maps-gain", "0"]) == 2
