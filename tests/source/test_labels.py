"""Labels as they come (issue #11 item 5): OpenTouch label tables with any name, delimiter and id column,
`htdata ingest --set ...` overrides recorded in the manifest, a missing table that says how to fix it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from htdata.source.adapters import get_adapter
from htdata.source.adapters.opentouch import detect_id_column, load_annotations, sniff_delimiter
from htdata.store.manifest import load_episodes, load_manifest
from htdata.synthetic.formats import write_opentouch_scene
from tests.factories import COLOURS, ingest_cli, ot_clip


def scene(root: Path) -> Path:
    write_opentouch_scene(root / "kitchen.hdf5", [ot_clip("demo_01", 5, COLOURS[0]), ot_clip("demo_2", 4, COLOURS[1])])
    return root


def tasks_of(out: Path) -> dict[str, str]:
    return {e["episode_id"]: e["task"] for e in load_episodes(out)}


@pytest.mark.parametrize("name,delim", [("clip_labels_v2.tsv", "\t"), ("labels.txt", ";"), ("labels.csv", ","),
                                        ("release-3.psv", "|")])
def test_any_name_and_delimiter_with_id_column_detected(tmp_path, name, delim):
    raw, out = scene(tmp_path / "raw"), tmp_path / "ds"
    table = tmp_path / "meta" / name
    table.parent.mkdir()
    rows = [["clip", "action", "comment"], ["kitchen::demo_01", "pour", "a, b; c"], ["kitchen::demo_002", "cut", "x"]]
    table.write_text("\n".join(delim.join(r if delim != "," else [f'"{c}"' for c in r]) for r in rows) + "\n")
    assert ingest_cli("--pipeline", "opentouch", "--set", f"adapter.params.annotations={table}", raw, out) == 0
    # demo_2 matches demo_002 by clip number; the id column "clip" was found by its values
    assert tasks_of(out) == {"ot-kitchen-demo_01": "pour", "ot-kitchen-demo_2": "cut"}
    (src,) = load_manifest(out)["sources"]
    assert src["adapter"]["params"]["annotations"] == str(table)      # provenance: the effective settings


def test_id_column_param_chooses_among_several(tmp_path):
    table = tmp_path / "labels.csv"
    table.write_text("id,alias,action\nkitchen::demo_01,kitchen::demo_09,pour\n")
    with pytest.raises(ValueError, match=r"several columns hold .* \(\['alias_x', 'alias'\]\); choose one with "
                                         r"--set adapter.params.id_column=COLUMN"):
        detect_id_column(["alias_x", "alias", "id2"], [{"alias": "a::b", "alias_x": "c::d"}], table)
    assert load_annotations(table, "action") == {"kitchen::demo_01": "pour"}            # "id" preferred
    assert load_annotations(table, "action", "alias") == {"kitchen::demo_09": "pour"}


def test_no_id_like_column_names_the_fix(tmp_path):
    table = tmp_path / "labels.csv"
    table.write_text("name,action\ndemo_01,pour\n")
    with pytest.raises(ValueError, match=r"no column .*'<scene>::<demo_id>'.*--set adapter.params.id_column=COLUMN"):
        load_annotations(table, "action")


def test_sniff_delimiter_prefers_consistent_header_split():
    assert sniff_delimiter(["a;b;c", "x,y;1;2", "p;q;r"], ".txt") == ";"
    assert sniff_delimiter(["a,b", "1,2"], ".tsv") == "\t"
    assert sniff_delimiter(["a\tb\tc", "1\t2\t3"], ".csv") == "\t"


def test_missing_table_is_an_error_printing_the_fix(tmp_path, capsys):
    raw, out = scene(tmp_path / "raw"), tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 2     # the shipped pipeline names annotations.csv
    err = capsys.readouterr().err
    assert "annotation table 'annotations.csv' not found" in err
    assert "--set adapter.params.annotations=PATH" in err and "--set adapter.params.allow_unlabelled=true" in err


def test_allow_unlabelled_ingests_with_warning_and_note(tmp_path, caplog):
    raw, out = scene(tmp_path / "raw"), tmp_path / "ds"
    with caplog.at_level(logging.WARNING, logger="htdata.source.adapters.opentouch"):
        assert ingest_cli("--pipeline", "opentouch", "--set", "adapter.params.allow_unlabelled=true", raw, out) == 0
    assert set(tasks_of(out).values()) == {"unlabelled"}
    assert any("not found" in r.getMessage() and "unlabelled" in r.getMessage() for r in caplog.records)
    for ep in load_episodes(out):
        assert any("annotation table" in n and "allow_unlabelled" in n for n in ep["notes"])
    (src,) = load_manifest(out)["sources"]
    assert src["adapter"]["params"]["allow_unlabelled"] is True


def test_set_is_validated_like_the_file(tmp_path, capsys):
    raw, out = scene(tmp_path / "raw"), tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", "--set", "adapter.params.annotaions=x.csv", raw, out) == 2
    err = capsys.readouterr().err
    assert "adapter.params.annotaions is not a param of adapter 'opentouch'" in err and "annotations (str" in err
    assert ingest_cli("--pipeline", "opentouch", "--set", "sync.max_skew_ms=nan", raw, out) == 2
    assert "sync.max_skew_ms must be a finite number" in capsys.readouterr().err
    assert ingest_cli("--pipeline", "opentouch", "--set", "native:sync.max_skew_ms=5", raw, out) == 2
    assert "no pipeline named 'native'" in capsys.readouterr().err
    assert not (out / "dataset.json").exists()


def test_pipeline_prefixed_set_aims_at_one_pipeline(tmp_path):
    raw, out = scene(tmp_path / "raw"), tmp_path / "ds"
    (raw / "annotations.csv").write_text("id,action\nkitchen::demo_01,pour\n")
    assert ingest_cli("--pipeline", "opentouch", "--set", "opentouch:adapter.params.task_field=action",
                      "--set", "opentouch:sync.max_skew_ms=10", raw, out) == 0
    (src,) = load_manifest(out)["sources"]
    assert src["sync"]["max_skew_ms"] == 10.0
    assert tasks_of(out) == {"ot-kitchen-demo_01": "pour", "ot-kitchen-demo_2": "unlabelled"}


def test_discovery_reads_the_table_from_params(tmp_path):
    raw = scene(tmp_path / "raw")
    (raw / "v3_labels.tsv").write_text("action\tkey\npour\tkitchen::demo_1\n")
    refs = get_adapter("opentouch").discover(raw, {"annotations": "v3_labels.tsv"})
    assert [(r.episode_id, r.task, r.extra["task_source"]) for r in refs] == [
        ("ot-kitchen-demo_01", "pour", "annotations"), ("ot-kitchen-demo_2", "unlabelled",
                                                        "fallback: clip missing from annotations")]
