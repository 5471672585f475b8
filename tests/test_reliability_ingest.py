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
