"""Glove layouts as the user meets them at ingest: a layout that is NOT shipped, resolved once.

A new 32x32 two-hand glove (left + right layout JSON written in tmp_path) is
ingested from native recordings through every place a user layout can
live: `--layouts DIR`, $HTDATA_LAYOUTS, a path in the pipeline's [layouts]
(relative to the pipeline file) and a file inside the recording folder.
The dataset must carry the layouts (self-contained) and read back.
"""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from htdata.glove.layouts import LAYOUTS_ENV, parse_layout
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from tests.factories import COLOURS, PERIOD, ingest_cli, small_pipeline

GLOVE = {"left": "my_glove_left_32x32", "right": "my_glove_right_32x32"}
FINGERS = ("little", "ring", "middle", "index", "thumb")   # right hand: little on the left, thumb on the right


def glove_layout(hand: str) -> dict:
    """A 32x32 glove: rows 0-15 five finger bands of 6 columns, rows 16-31 the palm; two bend cells."""
    blocks = []
    for n, finger in enumerate(FINGERS):
        c0 = 6 * n if hand == "right" else 31 - 6 * n - 5   # the left glove's columns run mirrored
        blocks.append({"name": finger, "place": finger, "rows": [0, 15], "cols": [c0, c0 + 5],
                       "flip_x": hand == "left", "flip_y": False})
    blocks.append({"name": "palm", "place": "palm", "rows": [16, 31], "cols": [0, 31],
                   "flip_x": hand == "left", "flip_y": False})
    bend_col = 30 if hand == "right" else 0
    return {"layout_id": GLOVE[hand], "hand": hand, "grid": [32, 32], "value": {"convention": "direct", "max": 1.0},
            "blocks": blocks, "dead_cells": [[0, 2]], "bend_cells": [[0, bend_col], [1, bend_col]],
            "source": "test glove (tests/ingest/test_ingest_layouts.py)"}


def write_glove(folder: Path) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for hand in ("left", "right"):
        out[hand] = folder / f"{GLOVE[hand]}.json"
        out[hand].write_text(json.dumps(glove_layout(hand), indent=1))
    return out


def write_recordings(root: Path, layout_names: dict[str, str], layout_files: dict[str, Path] | None = None) -> Path:
    """Two native recordings of the glove, both hands; `layout_files` are copied into each recording folder."""
    for n in range(2):
        t_video = np.arange(6, dtype=np.int64) * PERIOD
        t_glove = np.arange(0, 6 * PERIOD, 10_000_000, dtype=np.int64)
        hands = {}
        for hand in ("left", "right"):
            values = np.full((t_glove.size, 32, 32), np.nan, np.float32)
            live = parse_layout(glove_layout(hand), "glove").live_mask
            values[:, live] = 0.25 + 0.5 * n
            values[:, :2, 30 if hand == "right" else 0] = 0.75    # bend cells
            hands[hand] = NativeHand(layout_names[hand], values, t_glove)
        folder = root / f"session_{n}"
        write_native_recording(folder, NativeRecording(
            task="grasp", scene="lab", video_storage="jpeg",
            video_frames=[np.full((40, 40, 3), COLOURS[n], np.uint8)] * 6, video_timestamps_ns=t_video, hands=hands))
        for hand, path in (layout_files or {}).items():
            shutil.copy(path, folder / Path(layout_names[hand]))
    return root


def check_dataset(out: Path) -> None:
    from htdata.read.reader import DatasetReader

    reader = DatasetReader(out)
    assert len(reader) == 12 and {e["episode_id"] for e in reader.episodes} == {"nat-session_0", "nat-session_1"}
    for e in reader.episodes:
        assert e["layouts"] == GLOVE
    stored = {p.stem for p in (out / "layouts").glob("my_glove_*.json")}
    assert stored == set(GLOVE.values())            # self-contained: the layouts travel with the dataset
    for hand, lid in GLOVE.items():
        doc = json.loads((out / "layouts" / f"{lid}.json").read_text())
        assert doc["grid"] == [32, 32] and doc["hand"] == hand
    d = reader.decoded(reader.episode_range(1)[0] + 2)
    for hand in ("left", "right"):
        m = d["tactile"][hand]
        assert m.shape == (224, 224) and np.isclose(m.max(), 0.75, atol=1e-3)
    s = reader.sample(0)
    assert np.allclose(np.load(io.BytesIO(s["bend_left.npy"])), 0.75)


@pytest.fixture
def glove_dir(tmp_path) -> Path:
    write_glove(tmp_path / "my_gloves")
    return tmp_path / "my_gloves"


def test_layouts_dir_option(tmp_path, glove_dir, monkeypatch):
    monkeypatch.delenv(LAYOUTS_ENV, raising=False)
    raw = write_recordings(tmp_path / "raw", GLOVE)
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", glove_dir, "--pipeline", small_pipeline(tmp_path, "native"), raw, out,
                      workers=2) == 0
    check_dataset(out)


def test_layouts_env_search_path(tmp_path, glove_dir, monkeypatch):
    monkeypatch.setenv(LAYOUTS_ENV, f"{tmp_path / 'nowhere'}:{glove_dir}")
    raw = write_recordings(tmp_path / "raw", GLOVE)
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), raw, tmp_path / "ds") == 0
    check_dataset(tmp_path / "ds")


def test_layout_file_inside_the_recording_folder(tmp_path, glove_dir, monkeypatch):
    monkeypatch.delenv(LAYOUTS_ENV, raising=False)
    names = {h: f"glove/{lid}.json" for h, lid in GLOVE.items()}
    (tmp_path / "raw").mkdir()
    for n in range(2):
        (tmp_path / "raw" / f"session_{n}" / "glove").mkdir(parents=True)
    raw = write_recordings(tmp_path / "raw", names, {h: glove_dir / f"{lid}.json" for h, lid in GLOVE.items()})
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), raw, tmp_path / "ds") == 0
    check_dataset(tmp_path / "ds")


def test_pipeline_layouts_path_relative_to_the_pipeline(tmp_path, glove_dir, monkeypatch):
    monkeypatch.delenv(LAYOUTS_ENV, raising=False)
    raw = write_recordings(tmp_path / "raw", {"left": "touchanything_left_21x21", "right": "opentouch_right_16x16"})
    pipe = small_pipeline(tmp_path, "native")      # written in tmp_path: my_gloves/ sits beside it
    text = pipe.read_text().replace("[sync]", "[layouts]\nleft = \"my_gloves/my_glove_left_32x32.json\"\n"
                                              "right = \"my_gloves/my_glove_right_32x32.json\"\n\n[sync]")
    pipe.write_text(text)
    assert ingest_cli("--pipeline", pipe, raw, tmp_path / "ds") == 0
    check_dataset(tmp_path / "ds")


def test_missing_layout_is_one_line_naming_what_exists(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(LAYOUTS_ENV, raising=False)
    raw = write_recordings(tmp_path / "raw", GLOVE)
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", tmp_path / "empty", "--pipeline", small_pipeline(tmp_path, "native"), raw,
                      out) == 2   # nothing could be ingested
    err = capsys.readouterr().err
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert {f["stage"] for f in report["failures"]} == {"plan"} and len(report["failures"]) == 2
    msg = report["failures"][0]["error"]
    assert "my_glove_left_32x32" in msg and "opentouch_right_16x16" in msg and str(tmp_path / "empty") in msg
    assert "\n" not in msg and "Traceback" not in err
    # a pipeline override that does not resolve stops the ingest before any work, in one line
    pipe = small_pipeline(tmp_path, "native")
    pipe.write_text(pipe.read_text().replace("[sync]", "[layouts]\nright = \"no_such_glove\"\n\n[sync]"))
    assert ingest_cli("--pipeline", pipe, raw, tmp_path / "ds2") == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("htdata ingest: error:") and err.count("\n") == 0 and "no_such_glove" in err
    assert "opentouch_right_16x16" in err


def test_pipelines_with_different_codec_settings_are_refused(tmp_path, capsys):
    raw = tmp_path / "raw"
    (raw / "a").mkdir(parents=True), (raw / "b").mkdir()
    a = small_pipeline(tmp_path, "native")
    b = tmp_path / "other.toml"
    b.write_text(a.read_text().replace('name = "native"', 'name = "other"', 1).replace("quality = 95", "quality = 80"))
    assert ingest_cli("--pipeline", f"{a}={raw / 'a'}", "--pipeline", f"{b}={raw / 'b'}", tmp_path / "ds") == 2
    err = capsys.readouterr().err
    assert "rgb.quality" in err and "'native'" in err and "'other'" in err and "95 vs 80" in err
