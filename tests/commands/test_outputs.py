"""One rule for every command that writes a file or folder (htdata/commands/outputs.py): a missing
folder above the output is created and named on stderr, never silently; a file in its way is one line."""

from __future__ import annotations

import pytest

from htdata.cli import main as cli_main
from htdata.commands.outputs import OutputFolderError, output_path
from tests.factories.tactile import RIGHT, clean_series, write_taxel_dataset


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return write_taxel_dataset(tmp_path_factory.mktemp("out") / "ds", [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": {"right": (RIGHT, clean_series(RIGHT, 24, 1))}}])


def _commands(ds, new):
    """(command name, argv, what it writes) for each command that writes a file or folder."""
    yield "preview", ["preview", str(ds), str(new / "a" / "p.png")], new / "a" / "p.png"
    yield "stats", ["stats", str(ds), "--brief", "--health", str(new / "b" / "h.png")], new / "b" / "h.png"
    yield "validate", ["validate", str(ds), "--json", str(new / "c" / "v.json")], new / "c" / "v.json"
    yield "layouts render", ["layouts", "render", "opentouch_right_16x16", str(new / "d" / "l.png")], new / "d" / "l.png"
    yield "card", ["card", str(ds), str(new / "e" / "card.html")], new / "e" / "card.html"


def test_every_writer_creates_a_missing_folder_and_says_so(ds, tmp_path, capsys):
    new = tmp_path / "new"
    for name, argv, written in _commands(ds, new):
        assert cli_main(argv) == 0, name
        err = capsys.readouterr().err
        assert f"htdata {name}: created folder {written.parent if name != 'preview' else new} for {written}" in err, \
            (name, err)
        assert written.is_file(), name


def test_an_existing_folder_is_used_quietly_and_a_file_in_the_way_is_one_line(ds, tmp_path, capsys):
    assert output_path(tmp_path / "p.png", "preview") == tmp_path / "p.png"
    assert capsys.readouterr().err == ""
    (tmp_path / "taken").write_text("a file")
    with pytest.raises(OutputFolderError, match="taken is a file, not a folder"):
        output_path(tmp_path / "taken" / "sub" / "p.png", "preview")
    assert cli_main(["preview", str(ds), str(tmp_path / "taken" / "p.png")]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith("htdata preview: error: ") and "taken is a file, not a folder" in line
