"""A layout id that names no glove in use is an error, never a silent fallback (issue 19 item 3).

`[normalise.<id>]`, `--set normalise.<id>.*` and `[layouts]` entries must
name a layout (hand) some recording of the source uses, unless the pipeline
lists the id in `shared_layouts`; the same in `htdata renormalise --set`. A
mis-spelt id in a native recording.json is named with that file on stderr.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from htdata.ingest.pipeline import PIPELINES_DIR, load_pipeline
from tests.factories import ingest_cli
from tests.factories.knitglove import draft_layout, knit_counts, write_glove_only

LID = "knit_right_16x16"


def _setup(tmp_path: Path, table: str = "", recording_layout: str = LID) -> tuple[Path, Path, Path]:
    gloves = tmp_path / "gloves"
    gloves.mkdir()
    (gloves / f"{LID}.json").write_text(json.dumps(draft_layout(unused=[[r, c] for r in range(4)
                                                                        for c in range(10, 16)])))
    write_glove_only(tmp_path / "raw" / "rec_a", recording_layout, knit_counts(frames=40))
    pipe = tmp_path / "glove.toml"
    pipe.write_text((PIPELINES_DIR / "native.toml").read_text() + "\n" + table)
    return gloves, pipe, tmp_path / "ds"


def _ingest(capsys, gloves, pipe, out, *extra) -> tuple[int, str]:
    capsys.readouterr()
    rc = ingest_cli("--layouts", gloves, "--pipeline", pipe, *extra, pipe.parent / "raw", out)
    return rc, capsys.readouterr().err


def test_misspelt_normalise_table_is_an_error_naming_the_ids_in_use(tmp_path, capsys):
    gloves, pipe, out = _setup(tmp_path, "[normalise.knit_rigth_16x16]\nmax_value = 1000\n")
    rc, err = _ingest(capsys, gloves, pipe, out)
    assert rc == 2 and not (out / "dataset.json").exists()
    line = err.strip()
    assert "\n" not in line and "Traceback" not in line
    assert "[normalise.knit_rigth_16x16] names layout 'knit_rigth_16x16'" in line
    assert f"layouts in use: {LID}; did you mean '{LID}'?" in line
    assert "shared_layouts" in line and str(pipe) in line


def test_misspelt_set_normalise_is_an_error_naming_the_set_item(tmp_path, capsys):
    gloves, pipe, out = _setup(tmp_path)
    rc, err = _ingest(capsys, gloves, pipe, out, "--set", "normalise.knit_right_16x61.max_value=1000")
    assert rc == 2
    assert "--set normalise.knit_right_16x61.max_value=1000 names layout 'knit_right_16x61'" in err
    assert f"did you mean '{LID}'?" in err


def test_shared_layouts_allows_a_table_for_another_source_on_purpose(tmp_path, capsys):
    gloves, pipe, out = _setup(tmp_path, "[normalise.other_glove_left_32x32]\nmax_value = 1000\n")
    text = pipe.read_text()
    # a top-level key must come before the first table
    pipe.write_text(text.replace('name = "native"\n', 'name = "native"\nshared_layouts = ["other_glove_left_32x32"]\n', 1))
    assert load_pipeline(pipe).shared_layouts == ["other_glove_left_32x32"]
    rc, err = _ingest(capsys, gloves, pipe, out)
    assert rc == 0, err


def test_shared_layouts_must_name_a_table_of_the_pipeline(tmp_path):
    pipe = tmp_path / "p.toml"
    pipe.write_text((PIPELINES_DIR / "native.toml").read_text()
                    .replace('name = "native"\n', 'name = "native"\nshared_layouts = ["knit_left"]\n', 1))
    with pytest.raises(ValueError, match="shared_layouts lists 'knit_left', which no"):
        load_pipeline(pipe)


def test_layouts_entry_for_a_hand_no_recording_has_is_an_error(tmp_path, capsys):
    gloves, pipe, out = _setup(tmp_path)
    (gloves / "knit_left_16x16.json").write_text(json.dumps({**draft_layout("knit_left_16x16"), "hand": "left"}))
    text = pipe.read_text().replace("[adapter]", '[layouts]\nleft = "knit_left_16x16"\n\n[adapter]', 1)
    pipe.write_text(text)
    rc, err = _ingest(capsys, gloves, pipe, out)
    assert rc == 2
    assert "[layouts] left = 'knit_left_16x16': no recording of source" in err and "hands in use: right" in err


def test_renormalise_set_with_a_misspelt_layout_is_an_error_not_a_silent_noop(tmp_path, capsys):
    from htdata.cli import main

    gloves, pipe, out = _setup(tmp_path)
    rc, err = _ingest(capsys, gloves, pipe, out)
    assert rc == 0, err
    rc = main(["renormalise", str(out), "--pipeline", "native", "--set", "normalise.knit_rihgt_16x16.max_value=1000",
               "--dry-run"])
    captured = capsys.readouterr()
    assert rc == 2
    assert "--set normalise.knit_rihgt_16x16.max_value=1000 names layout 'knit_rihgt_16x16'" in captured.err
    assert f"did you mean '{LID}'?" in captured.err and "would" not in captured.out
    # spelt right, it plans the change
    assert main(["renormalise", str(out), "--pipeline", "native", "--set", f"normalise.{LID}.max_value=1000",
                 "--dry-run"]) == 0
    assert "1 episode(s) would renormalised" in capsys.readouterr().out


def test_misspelt_layout_in_recording_json_names_the_id_and_the_file(tmp_path, capsys):
    gloves, pipe, out = _setup(tmp_path, recording_layout="knit_rihgt_16x16")
    rc, err = _ingest(capsys, gloves, pipe, out)
    assert rc == 2
    rec = tmp_path / "raw" / "rec_a" / "recording.json"
    assert "'knit_rihgt_16x16' not found" in err and str(rec) in err
    assert f"did you mean '{LID}'?" in err
