"""Out-of-range raw glove values and unusable hands (issue #11 item 4): counted, recorded, handled by policy.

Hard cases from the issue: OpenTouch -500 and 1e9 (inverted, range [0, 3072]), TouchAnything 1.5
(direct, [0, 1]), native -1e9. Default policy "clip" keeps the episode and records the counts (with a
warning note above 1% of frames); "drop_frame" drops the frames; "fail" fails the episode naming
file, episode and frame while the rest of the source is ingested.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from htdata.glove.layouts import load_layout
from htdata.store.manifest import load_episodes
from htdata.synthetic.formats import (
    NativeHand,
    NativeRecording,
    write_native_recording,
)
from tests.factories import COLOURS, PERIOD, ingest_cli
from tests.factories.outofrange import opentouch_raw, ta_episode


def report_of(out: Path) -> dict:
    return json.loads((out / "reports" / "ingest.json").read_text())


def episodes_of(out: Path) -> dict[str, dict]:
    return {e["episode_id"]: e for e in load_episodes(out)}


def test_clip_default_counts_and_records_out_of_range(tmp_path):
    raw, out = opentouch_raw(tmp_path / "raw"), tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 0
    eps = episodes_of(out)
    lay = load_layout("opentouch_right_16x16")
    expect_below = int(lay.live_mask[0, :3].sum())
    expect_above = int(lay.live_mask[3, 3]) + int(lay.live_mask[4, 4])
    assert expect_below and expect_above
    counts = eps["ot-kitchen-demo_02"]["out_of_range"]["right"]
    assert counts == {"below": expect_below, "above": expect_above, "frames": 3}
    assert eps["ot-kitchen-demo_02"]["num_frames"] == 10                      # clipped, kept
    assert any(n.startswith("warning: right hand: 3 of 10 frames (30.0%)") and "clipped" in n
               for n in eps["ot-kitchen-demo_02"]["notes"])
    assert "out_of_range" not in eps["ot-kitchen-demo_01"]                     # clean record unchanged
    assert report_of(out)["out_of_range"] == {"ot-kitchen-demo_02": {"right": counts}}


def test_clip_below_warn_share_counts_without_warning(tmp_path):
    raw, out = opentouch_raw(tmp_path / "raw"), tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", "--set", "normalise.out_of_range_warn_share=0.5", raw, out) == 0
    ep = episodes_of(out)["ot-kitchen-demo_02"]
    assert ep["out_of_range"]["right"]["frames"] == 3
    assert not any("outside" in n for n in ep["notes"])


def test_drop_frame_policy_drops_and_counts(tmp_path):
    raw, out = opentouch_raw(tmp_path / "raw"), tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", "--set", "normalise.out_of_range=drop_frame", raw, out) == 0
    ep = episodes_of(out)["ot-kitchen-demo_02"]
    # the 3 frames leave the pairing; their RGB frames stay as RGB-only samples (format 3), raw rows stored
    assert ep["stats"]["frames_kept"] == 7 and ep["dropped_frames"] == {"out_of_range:right": 3}
    assert ep["num_frames"] == 10 and ep["rgb_only_frames"] == {"out_of_range:right": 3}
    assert ep["out_of_range"]["right"]["frames"] == 3
    assert report_of(out)["dropped_frames"] == [
        {"episode_id": "ot-kitchen-demo_02", "rgb_index": i, "reason": "out_of_range:right"} for i in (2, 5, 6)]


def test_fail_policy_fails_only_that_episode_naming_the_frame(tmp_path, capsys):
    raw, out = opentouch_raw(tmp_path / "raw"), tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", "--set", "normalise.out_of_range=fail", raw, out) == 1
    err = capsys.readouterr().err
    assert "kitchen.hdf5 [ot-kitchen-demo_02] frame 2: right hand raw value -500 outside [0, 3072]" in err
    assert set(episodes_of(out)) == {"ot-kitchen-demo_01"}
    (failure,) = report_of(out)["failures"]
    assert failure["episode_id"] == "ot-kitchen-demo_02" and failure["frame"] == 2


def test_touchanything_value_above_one_is_counted(tmp_path):
    raw, out = tmp_path / "raw", tmp_path / "ds"
    ta_episode(raw / "Home" / "pour" / "t1", 6, right_value=1.5)
    assert ingest_cli("--pipeline", "touchanything", raw, out) == 0
    ep = episodes_of(out)["ta-Home-pour-t1"]
    assert ep["out_of_range"] == {"right": {"below": 0, "above": 1, "frames": 1}}
    assert report_of(out)["out_of_range"]["ta-Home-pour-t1"]["right"]["above"] == 1


@pytest.mark.parametrize("left", ["nan", None], ids=["all_nan", "missing"])
def test_touchanything_unusable_hand_is_recorded(tmp_path, left):
    raw, out = tmp_path / "raw", tmp_path / "ds"
    ta_episode(raw / "Home" / "pour" / "t1", 5, left=left)
    assert ingest_cli("--pipeline", "touchanything", raw, out) == 0
    ep = episodes_of(out)["ta-Home-pour-t1"]
    assert ep["hands"] == ["right"]
    why = "all-NaN" if left == "nan" else "no left_pressure_grid array in pressure_grids.npz"
    assert ep["hands_excluded"] == {"left": why}
    assert f"left hand not ingested: {why}" in ep["notes"]
    assert report_of(out)["hands_excluded"] == {"ta-Home-pour-t1": {"left": why}}


def test_native_minus_1e9_is_counted_not_silently_saturated(tmp_path):
    raw, out = tmp_path / "raw", tmp_path / "ds"
    t_video = np.arange(6, dtype=np.int64) * PERIOD
    values = np.full((6, 16, 16), 1536.0, np.float32)
    values[3] = -1e9
    rec = NativeRecording(task="grasp", scene="lab", video_storage="jpeg",
                          video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * 6, video_timestamps_ns=t_video,
                          hands={"right": NativeHand("opentouch_right_16x16", values, t_video)})
    write_native_recording(raw / "rec", rec)
    assert ingest_cli("--pipeline", "native", raw, out) == 0
    ep = episodes_of(out)["nat-rec"]
    n_live = int(load_layout("opentouch_right_16x16").live_mask.sum())
    assert ep["out_of_range"] == {"right": {"below": n_live, "above": 0, "frames": 1}}
    assert any("1 of 6 frames" in n for n in ep["notes"])
