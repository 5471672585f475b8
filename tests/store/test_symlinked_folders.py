"""Issue 35 item 6: writers never write or delete through a symlinked folder of a dataset.

With shards/, .work/, reports/, stats/, layouts/ or versions/ a symlink to a folder elsewhere, an append
deleted unrelated shard-*.tar / unit-*.json files there and wrote its shards there; validate and stats
wrote their report and cache there. Now every writer (it takes the writer lock: htdata/store/writable.py)
refuses in one line naming the link, before anything is written; validate refuses its default report
there; stats computes without the cache (one warning line). Readers read through such a folder as before.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import htdata
from htdata.cli import main as cli_main
from htdata.store.versions import list_versions
from tests.factories import ingest_cli, make_native

DECOYS = ("shard-000000-000.tar", "shard-000005-000.tar", "unit-000001.json", "ingest.json", "validate.json")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    base = tmp_path_factory.mktemp("built")
    raw = make_native(base / "raw")
    assert ingest_cli("--pipeline", "native", raw, base / "ds") == 0
    return base


def _dataset_with_symlinked(built, tmp_path, name: str) -> tuple[Path, Path, dict]:
    """A copy of the built dataset whose `name` folder is a symlink to `outside` (its content moved there,
    plus decoy files a writer would delete or overwrite); returns (dataset, outside, decoy bytes)."""
    root = Path(shutil.copytree(built / "ds", tmp_path / "ds", symlinks=True))
    outside = tmp_path / "elsewhere" / name.strip(".")
    outside.parent.mkdir()
    if (root / name).exists():
        shutil.move(root / name, outside)
    else:
        outside.mkdir()
    decoys = {}
    for i, decoy in enumerate(DECOYS):
        if not (outside / decoy).exists():
            (outside / decoy).write_bytes(b"not yours %d" % i)
            decoys[decoy] = (outside / decoy).read_bytes()
    (root / name).symlink_to(outside, target_is_directory=True)
    return root, outside, decoys


def _listing(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("name", ["shards", ".work", "reports", "stats", "layouts", "versions"])
def test_an_append_through_a_symlinked_folder_is_refused_naming_it(built, tmp_path, capsys, name):
    root, outside, decoys = _dataset_with_symlinked(built, tmp_path, name)
    before, versions = _listing(outside), list_versions(root)
    raw = tmp_path / "raw"
    shutil.copytree(built / "raw", raw)
    shutil.copytree(raw / "rec_good", raw / "rec_more")       # an append: one new episode
    capsys.readouterr()
    assert ingest_cli("--pipeline", "native", raw, root) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{root / name} is a symlink (to {outside})" in err[0], err
    assert _listing(outside) == before and all((outside / d).read_bytes() == b for d, b in decoys.items())
    assert list_versions(root) == versions and not (root / ".lock").exists()
    if name != "versions":     # a version's records outside the root are refused by store/confine.py
        assert len(htdata.open(root)) == 9          # readers still read through it


@pytest.mark.parametrize("command", [["split", "--ood-task", "none", "--name", "main"], ["rm", "nat-rec_good"],
                                     ["repair"], ["gc"]])
def test_every_writer_refuses_a_symlinked_shards_folder(built, tmp_path, capsys, command):
    root, outside, _ = _dataset_with_symlinked(built, tmp_path, "shards")
    before = _listing(outside)
    capsys.readouterr()
    assert cli_main([command[0], str(root), *command[1:]]) == 2
    err = capsys.readouterr().err
    assert f"{root / 'shards'} is a symlink" in err and "Traceback" not in err, err
    assert _listing(outside) == before and list_versions(root) == [1]


def test_validate_writes_no_report_through_a_symlinked_reports_folder(built, tmp_path, capsys):
    root, outside, _ = _dataset_with_symlinked(built, tmp_path, "reports")
    before = _listing(outside)
    capsys.readouterr()
    assert cli_main(["validate", str(root)]) == 2
    assert f"{root / 'reports'} is a symlink" in capsys.readouterr().err
    assert _listing(outside) == before
    assert cli_main(["validate", str(root), "--json", str(tmp_path / "report.json")]) == 0   # elsewhere: fine
    assert (tmp_path / "report.json").is_file() and _listing(outside) == before


def test_stats_reads_and_writes_no_cache_through_a_symlinked_stats_folder(built, tmp_path, capsys):
    root, outside, _ = _dataset_with_symlinked(built, tmp_path, "stats")
    before = _listing(outside)
    capsys.readouterr()
    assert cli_main(["stats", str(root), "--brief"]) == 0
    err = capsys.readouterr().err
    assert f"stats not cached: {root / 'stats'} is a symlink" in err, err
    assert _listing(outside) == before
