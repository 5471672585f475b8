"""Ingest killed mid-run, then its inputs edited: the resume honours the inputs as they are now.

Before issue 18 a unit finished before the kill was resumed from its record
whose fingerprint left the labels out: labels edited in between were lost
("relabelled 0"; only a second re-run fixed them).
"""

import os
import subprocess
import sys

from htdata.reader import DatasetReader
from tests.factories import ingest_cli, make_opentouch, small_pipeline


def test_labels_edited_between_a_crash_and_its_resume_are_honoured(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    # units run largest first: demo_003 (unit 0), demo_01 (unit 1), then demo_02 (unit 2) dies
    env = {**os.environ, "HTDATA_TEST_FAULT_UNIT": "2", "HTDATA_TEST_FAULT": "crash"}
    killed = subprocess.run([sys.executable, "-m", "htdata.cli", "ingest", "--workers", "0", "--quiet",
                             "--pipeline", str(pipe), str(raw), str(out)], env=env, capture_output=True, text=True)
    assert killed.returncode == 137, killed.stderr
    assert len(list((out / ".work").glob("unit-*.json"))) == 2          # two units finished before the kill
    csv = raw / "annotations.csv"
    csv.write_text(csv.read_text().replace(",pour", ",sip").replace(",wipe", ",scrub"))
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    tasks = {e["episode_id"]: e["task"] for e in DatasetReader(out).episodes}
    assert tasks == {"ot-home_kitchen_p1-demo_01": "sip", "ot-home_kitchen_p1-demo_02": "cut",
                     "ot-home_kitchen_p1-demo_003": "scrub"}


def test_glove_rows_long_after_the_video_are_dropped_with_a_count_not_piled_into_one_sample(tmp_path):
    import json

    import numpy as np

    from htdata.sample.formats import NativeHand, NativeRecording, write_native_recording
    from tests.factories import COLOURS, FRAME_NS

    t_video = np.arange(9, dtype=np.int64) * FRAME_NS                  # a 0.3 s video ...
    t_glove = np.arange(0, 200 * 10**9, 10_000_000, dtype=np.int64)     # ... beside 200 s of 100 Hz glove
    values = np.full((t_glove.size, 16, 16), 1536.0, np.float32)
    write_native_recording(tmp_path / "raw" / "rec", NativeRecording(
        task="grasp_cup", scene="lab", video_storage="jpeg", video_timestamps_ns=t_video,
        video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * 9,
        hands={"right": NativeHand("opentouch_right_16x16", values, t_glove)}))
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), tmp_path / "raw", out) == 0
    reader = DatasetReader(out)
    stored = set()
    for i in range(len(reader)):
        meta = json.loads(reader.sample(i)["json"])
        rows, times = meta["raw_row"]["right"], meta["raw_t_ns"]["right"]
        assert max(times) - min(times) <= 2 * 10**9, i                  # a bounded span per sample
        stored |= set(rows)
    beyond = int(np.count_nonzero(t_glove >= t_video[-1] + 10**9))      # more than 1 s after the last frame
    assert len(stored) == t_glove.size - beyond                          # everything else is kept
    record = reader.episodes[0]
    assert record["raw_rows_dropped"] == {"right": beyond}
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert any(f"{beyond} right glove rows" in n for n in report["notes"])
