"""The version files are the truth, dataset.json their cache: a damaged or missing pointer loses nothing.

Each test here fails on the code before issue 18 (where dataset.json was the
only record of the current version: deleting it made the next ingest wipe
the folder, rolling it back made the next write delete later versions).
"""

import json
import shutil
import subprocess
import sys

import pytest

from htdata.errors import HtdataError
from htdata.read.reader import DatasetReader
from htdata.store.versions import list_versions
from htdata.synthetic.formats import write_opentouch_scene
from tests.factories import COLOURS, ingest_cli, make_opentouch, ot_clip, small_pipeline, write_synthetic_dataset

EPISODES = [{"episode_id": f"ep_{i}", "task": "pour" if i % 2 else "wipe", "scene": "lab", "hands": ("right",),
             "num_frames": 3 + i} for i in range(5)]


def htdata(*args):
    return subprocess.run([sys.executable, "-m", "htdata.cli", *map(str, args)], capture_output=True, text=True)


def files(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*")
            if p.is_file() and p.parts[len(root.parts)] in ("shards", "versions")}


def three_versions(root):
    root = write_synthetic_dataset(root, EPISODES)
    assert htdata("rm", root, "ep_0").returncode == 0
    assert htdata("rm", root, "ep_1").returncode == 0
    assert list_versions(root) == [1, 2, 3]
    return root


def test_missing_pointer_is_not_a_new_dataset_ingest_appends_and_deletes_nothing(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    assert htdata("rm", out, "ot-home_kitchen_p1-demo_02").returncode == 0
    write_opentouch_scene(raw / "z.hdf5", [ot_clip("demo_01", 5, COLOURS[3])])
    with open(raw / "annotations.csv", "a") as f:
        f.write("z::demo_01,pour,,,,\n")
    before = files(out)
    (out / "dataset.json").unlink()
    assert len(DatasetReader(out, version=1)) == 39          # old versions read without the pointer
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    assert list_versions(out) == [1, 2, 3]
    now = DatasetReader(out)
    assert now.manifest["parent"] == 2 and len(now.episodes) == 4   # demo_02 is back (its source is there), z added
    after = files(out)
    assert {k: v for k, v in after.items() if k in before} == before     # nothing committed deleted or changed
    assert json.loads((out / "dataset.json").read_text())["version"] == 3


def test_truncated_pointer_leaves_every_version_readable(tmp_path):
    root = three_versions(tmp_path / "ds")
    data = (root / "dataset.json").read_bytes()
    (root / "dataset.json").write_bytes(data[:len(data) // 3])
    assert DatasetReader(root).version == 3
    assert [len(DatasetReader(root, version=v)) for v in (1, 2, 3)] == [25, 22, 18]
    assert htdata("validate", root).returncode != 0                       # the stale cache is reported ...
    fixed = htdata("repair", root)
    assert fixed.returncode == 0 and "rewrite dataset.json" in fixed.stdout
    assert (root / "dataset.json").read_bytes() == (root / "versions" / "v000003.json").read_bytes()
    assert htdata("validate", root).returncode == 0                       # ... and repaired


def test_pointer_rolled_back_by_hand_never_makes_a_writer_delete_later_versions(tmp_path):
    root = three_versions(tmp_path / "ds")
    before = files(root)
    shutil.copyfile(root / "versions" / "v000001.json", root / "dataset.json")
    res = htdata("split", root, "--ood-task", "pour", "--name", "main")
    assert res.returncode == 0, res.stderr
    assert list_versions(root) == [1, 2, 3, 4] and DatasetReader(root).manifest["parent"] == 3
    after = files(root)
    assert {k: v for k, v in after.items() if k in before} == before


def test_repair_dry_run_writes_nothing(tmp_path):
    root = three_versions(tmp_path / "ds")
    (root / "dataset.json").unlink()
    res = htdata("repair", root, "--dry-run")
    assert res.returncode == 0 and "would rewrite dataset.json (missing)" in res.stdout
    assert not (root / "dataset.json").exists()


def test_deleted_current_version_file_is_named_with_its_fix(tmp_path):
    root = three_versions(tmp_path / "ds")
    current = root / "versions" / "v000003.json"
    keep = current.read_bytes()
    current.unlink()
    with pytest.raises(HtdataError, match=r"v000003\.json: missing.*htdata repair"):
        DatasetReader(root)
    for cmd in (["validate", root], ["log", root], ["rm", root, "ep_2"]):
        res = htdata(*cmd)
        assert res.returncode != 0 and "v000003.json" in res.stdout + res.stderr and "Traceback" not in res.stderr, cmd
    assert list_versions(root) == [1, 2]                                   # rm wrote nothing on top of v2
    res = htdata("repair", root)
    assert res.returncode == 0 and "restore versions/v000003.json" in res.stdout
    assert current.read_bytes() == keep and DatasetReader(root).version == 3


def test_garbled_current_version_file_is_named(tmp_path):
    root = three_versions(tmp_path / "ds")
    current = root / "versions" / "v000003.json"
    current.write_bytes(current.read_bytes()[:40])
    for cmd in (["validate", root], ["log", root]):
        res = htdata(*cmd)
        assert res.returncode != 0 and "v000003.json" in res.stdout + res.stderr and "Traceback" not in res.stderr, cmd
    assert htdata("repair", root).returncode == 0                          # dataset.json still holds a copy
    assert DatasetReader(root).version == 3 and htdata("validate", root).returncode == 0
