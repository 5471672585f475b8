"""What a user sees on the console: excluded hands and out-of-range values reach stderr, an empty
source folder is an error, a label table with two tasks for one id is an error naming both rows.
Before issue 18 the first two were only in reports/ingest.json, an empty folder exited 0 when
appending, and the last row of a conflicting label table silently won."""

import pytest

from htdata.synthetic.formats import write_opentouch_annotations
from tests.factories import ingest_cli, make_native, make_opentouch, small_pipeline
from tests.factories.outofrange import opentouch_raw, ta_episode


def test_out_of_range_values_reach_stderr(tmp_path, capsys):
    raw = opentouch_raw(tmp_path / "raw")
    assert ingest_cli("--pipeline", "opentouch", raw, tmp_path / "ds") == 0
    err = capsys.readouterr().err
    assert "note: ot-kitchen-demo_02: right hand: 3 frames hold raw values outside the layout range" in err


def test_excluded_hand_reaches_stderr(tmp_path, capsys):
    raw = tmp_path / "raw"
    ta_episode(raw / "Home" / "pour" / "t1", 5, left="nan")
    assert ingest_cli("--pipeline", "touchanything", raw, tmp_path / "ds") == 0
    assert "note: ta-Home-pour-t1: left hand not ingested: all-NaN" in capsys.readouterr().err


@pytest.mark.parametrize("existing", [False, True], ids=["new", "append"])
def test_empty_source_folder_is_an_error(tmp_path, capsys, existing):
    out = tmp_path / "ds"
    pipe = small_pipeline(tmp_path, "native")
    if existing:
        assert ingest_cli("--pipeline", pipe, make_native(tmp_path / "raw"), out) == 0
    empty = tmp_path / "empty"
    empty.mkdir()
    capsys.readouterr()
    assert ingest_cli("--pipeline", pipe, empty, out) == 2
    err = capsys.readouterr().err
    assert f"no native recordings (recording.json) under {empty}" in err and "Traceback" not in err


def test_duplicate_annotation_id_with_conflicting_task_names_both_rows(tmp_path, capsys):
    raw = make_opentouch(tmp_path / "raw")
    write_opentouch_annotations(raw / "annotations.csv", [
        {"id": "home_kitchen_p1::demo_01", "action": "pour"}, {"id": "home_kitchen_p1::demo_02", "action": "cut"},
        {"id": "home_kitchen_p1::demo_003", "action": "wipe"}, {"id": "home_kitchen_p1::demo_01", "action": "stir"}])
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, tmp_path / "ds") == 2
    err = capsys.readouterr().err
    assert ("id 'home_kitchen_p1::demo_01' is labelled twice with different tasks: line 2 says 'pour', "
            "line 5 says 'stir'") in err
    assert not (tmp_path / "ds" / "dataset.json").exists()
