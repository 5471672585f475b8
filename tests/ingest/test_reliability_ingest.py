"""Ingest killed mid-run, then its inputs edited: the resume honours the inputs as they are now.

Before issue 18 a unit finished before the kill was resumed from its record
whose fingerprint left the labels out: labels edited in between were lost
("relabelled 0"; only a second re-run fixed them).
"""

import json

import pytest

from htdata.read.reader import DatasetReader
from tests.factories import ingest_cli, ingest_crashing_at_unit, make_native, make_opentouch, small_pipeline


def test_labels_edited_between_a_crash_and_its_resume_are_honoured(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    # units run largest first: demo_003 (unit 0), demo_01 (unit 1), then demo_02 (unit 2) dies
    killed = ingest_crashing_at_unit(2, "--pipeline", pipe, raw, out)
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

    from tests.factories import FRAME_NS

    t_video = np.arange(9, dtype=np.int64) * FRAME_NS                  # a 0.3 s video ...
    t_glove = np.arange(0, 200 * 10**9, 10_000_000, dtype=np.int64)     # ... beside 200 s of 100 Hz glove
    _flat_right_glove_recording(tmp_path / "raw" / "rec", t_video, t_glove)
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


def _sums(raw, files):
    import hashlib

    lines = [f"{hashlib.sha256((raw / f).read_bytes()).hexdigest()}  {f}" for f in files]
    (raw / "SHA256SUMS").write_text("\n".join(lines) + "\n")


def test_every_record_keeps_its_source_files_sha256(tmp_path):
    import hashlib

    raw = make_opentouch(tmp_path / "raw")
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, tmp_path / "ds") == 0
    want = hashlib.sha256((raw / "home_kitchen_p1.hdf5").read_bytes()).hexdigest()
    labels = hashlib.sha256((raw / "annotations.csv").read_bytes()).hexdigest()   # it decides the task (#26)
    assert {e["episode_id"]: e["source_sha256"] for e in DatasetReader(tmp_path / "ds").episodes} == {
        e: {"home_kitchen_p1.hdf5": want, "annotations.csv": labels} for e in ("ot-home_kitchen_p1-demo_01", "ot-home_kitchen_p1-demo_02",
                                                   "ot-home_kitchen_p1-demo_003")}


def test_a_copy_that_differs_from_sha256sums_is_refused_with_verify_sources(tmp_path, capsys):
    raw = make_opentouch(tmp_path / "raw")
    # both files the episodes read are listed: an unlisted one fails them before any unit runs (#37)
    _sums(raw, ["home_kitchen_p1.hdf5", "annotations.csv"])
    data = bytearray((raw / "home_kitchen_p1.hdf5").read_bytes())
    data[-100] ^= 0x01                                   # one flipped bit a decoder may never notice
    (raw / "home_kitchen_p1.hdf5").write_bytes(bytes(data))
    pipe = small_pipeline(tmp_path, "opentouch")
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, tmp_path / "strict") == 2   # nothing left
    err = capsys.readouterr().err
    assert "no episode could be ingested (3 failures)" in err
    report = json.loads((tmp_path / "strict" / "reports" / "ingest.json").read_text())
    assert {f["stage"] for f in report["failures"]} == {"verify"}
    assert "differs from" in report["failures"][0]["error"] and "SHA256SUMS:1" in report["failures"][0]["error"]
    assert ingest_cli("--pipeline", pipe, raw, tmp_path / "lenient") == 0                      # warned
    err = capsys.readouterr().err
    assert err.count("home_kitchen_p1.hdf5: sha256") == 1 and "ingested anyway" in err


def test_verify_sources_passes_matching_files_and_refuses_unlisted_ones(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, tmp_path / "none") == 2      # no list at all
    _sums(raw, ["home_kitchen_p1.hdf5"])                # the label table decides tasks: it must be listed too
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, tmp_path / "unlisted") == 2
    _sums(raw, ["home_kitchen_p1.hdf5", "annotations.csv"])
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, tmp_path / "ok") == 0
    assert len(DatasetReader(tmp_path / "ok").episodes) == 3


def test_timestamps_are_read_in_bounded_blocks_not_via_whole_length_index_arrays(tmp_path):
    import tracemalloc

    import numpy as np

    from htdata.source.adapters.npzrows import NpzRows

    ts = np.arange(1_000_000, dtype=np.int64) * 10_000_000          # 8 MB of timestamps, compresses well
    np.savez_compressed(tmp_path / "t.npz", timestamps_ns=ts)
    rows = NpzRows(tmp_path / "t.npz", "timestamps_ns")
    tracemalloc.start()
    try:
        got = rows.read_all()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        rows.close()
    assert np.array_equal(got, ts)
    assert peak < ts.nbytes + 6 * 2**20, peak     # the array + ~1 MB blocks; before #18: ~4x the array


def test_a_native_recordings_own_layout_json_is_hashed_and_verified(tmp_path):
    """Issue 26 item 5: the layout JSON a recording keeps decides its maps; before, it was neither in
    source_sha256 nor checked by --verify-sources (damaged after SHA256SUMS, it ingested with rc 0)."""
    import shutil

    from htdata.resources import SCHEMAS_DIR

    raw = make_native(tmp_path / "raw")
    rec = raw / "rec_good"
    doc = json.loads((rec / "recording.json").read_text())
    layout = json.loads((SCHEMAS_DIR / "layouts" / "opentouch_right_16x16.json").read_text())
    layout["layout_id"] = "my_glove_right_16x16"
    (rec / "my_glove.json").write_text(json.dumps(layout, indent=1))
    doc["hands"]["right"]["layout"] = "my_glove.json"
    (rec / "recording.json").write_text(json.dumps(doc, indent=1))
    _sums(raw, sorted(p.relative_to(raw).as_posix() for p in raw.rglob("*") if p.is_file()))
    pipe = small_pipeline(tmp_path, "native")
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, tmp_path / "ok") == 0
    assert "rec_good/my_glove.json" in DatasetReader(tmp_path / "ok").episodes[0]["source_sha256"]
    layout["value"]["max"] = 1536                       # damaged after SHA256SUMS was written: other maps
    (rec / "my_glove.json").write_text(json.dumps(layout, indent=1))
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, tmp_path / "strict") == 2
    report = json.loads((tmp_path / "strict" / "reports" / "ingest.json").read_text())
    assert "my_glove.json" in report["failures"][0]["file"] and "differs from" in report["failures"][0]["error"]
    shutil.rmtree(tmp_path / "ok")


@pytest.mark.parametrize("how", ["packed", "stuck"])
def test_glove_rows_per_sample_are_bounded_by_count(tmp_path, capsys, how):
    """Issue 26 item 6: rows packed 100 ns apart inside the 1-s window after the last frame (or a stuck glove
    clock: thousands of rows at one timestamp) all went into one sample (3.5 GB RSS for a 2.8 MB npz)."""
    import numpy as np

    from htdata.ingest.fullrate import raw_row_cap
    from tests.factories import FRAME_NS

    t_video = np.arange(9, dtype=np.int64) * FRAME_NS
    t_glove = np.arange(0, 9 * FRAME_NS, 10_000_000, dtype=np.int64)               # 100 Hz beside the video
    extra = 20_000
    start = t_video[-1] + 1_000_000
    burst = start + np.arange(extra, dtype=np.int64) * 100 if how == "packed" else np.full(extra, start)
    t_all = np.concatenate([t_glove, burst])
    _flat_right_glove_recording(tmp_path / "raw" / "rec", t_video, t_all)
    out = tmp_path / "ds"
    capsys.readouterr()
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "native"), tmp_path / "raw", out) == 0
    err = capsys.readouterr().err
    cap = raw_row_cap(t_all, 10**9)
    assert cap == (4016 if how == "packed" else 216)     # 2 kHz at most (packed), else the glove's 100 Hz
    reader = DatasetReader(out)
    stored = [len(json.loads(reader.sample(i)["json"])["raw_row"]["right"]) for i in range(len(reader))]
    assert max(stored) <= cap + 1                                          # + the paired row
    capped = reader.episodes[0]["raw_rows_capped"]["right"]
    assert capped >= extra - cap
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert report["raw_rows_capped"] == {"nat-rec": {"right": capped}}
    assert f"{capped} glove rows dropped over the {cap} rows one sample may store" in err


def _flat_right_glove_recording(folder, t_video, t_glove):
    """A native recording: 9 one-colour JPEG frames at `t_video`, a right OpenTouch glove resting at `t_glove`."""
    import numpy as np

    from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
    from tests.factories import COLOURS

    values = np.full((t_glove.size, 16, 16), 1536.0, np.float32)
    write_native_recording(folder, NativeRecording(
        task="grasp_cup", scene="lab", video_storage="jpeg", video_timestamps_ns=t_video,
        video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * 9,
        hands={"right": NativeHand("opentouch_right_16x16", values, t_glove)}))
