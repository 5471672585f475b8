"""Issue 35 item 3: every HDF5 link on the way to a dataset resolved inside the file.

A soft link to an external link (or through one) got past the external-link refusal and ingested the
outside file's bytes, which `source_sha256` never hashed; a dangling soft link failed the whole scene file
at discovery with a bare KeyError. Now each component is resolved link by link (htdata/source/adapters/
hdf5safe.py): leaving the file is refused, a dangling link or a loop is named, and only that clip fails.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from htdata.store.manifest import load_episodes
from tests.factories import ingest_cli, make_opentouch

SCENE = "home_kitchen_p1.hdf5"
OTHERS = ["ot-home_kitchen_p1-demo_003", "ot-home_kitchen_p1-demo_01"]


def _outside(g, outside: Path) -> None:
    with h5py.File(outside, "w") as o:
        o.create_dataset("p", data=np.asarray(g["right_pressure"][()], np.float32))


def soft_to_external(f, g, outside: Path) -> None:
    _outside(g, outside)
    f["ext"] = h5py.ExternalLink(str(outside), "/p")
    del g["right_pressure"]
    g["right_pressure"] = h5py.SoftLink("/ext")


def soft_through_external_group(f, g, outside: Path) -> None:
    _outside(g, outside)
    f["alias"] = h5py.ExternalLink(str(outside), "/")
    del g["right_pressure"]
    g["right_pressure"] = h5py.SoftLink("/alias/p")


def relative_soft_chain_to_external(f, g, outside: Path) -> None:
    _outside(g, outside)
    g["ext"] = h5py.ExternalLink(str(outside), "/p")
    g["hop"] = h5py.SoftLink("ext")                  # relative: resolved in the link's own group
    del g["right_pressure"]
    g["right_pressure"] = h5py.SoftLink("hop")


def dangling(f, g, outside: Path) -> None:
    del g["right_pressure"]
    g["right_pressure"] = h5py.SoftLink("/nowhere/p")


def loop(f, g, outside: Path) -> None:
    del g["right_pressure"]
    g["right_pressure"] = h5py.SoftLink("/data/demo_02/again")
    g["again"] = h5py.SoftLink("/data/demo_02/right_pressure")


def dangling_clip(f, g, outside: Path) -> None:
    f.move("data/demo_02", "moved")
    f["data/demo_02"] = h5py.SoftLink("/gone")


@pytest.mark.parametrize("how,said", [
    (soft_to_external, "/data/demo_02/right_pressure -> /ext: an HDF5 external link to "),
    (soft_through_external_group, "/data/demo_02/right_pressure -> /alias: an HDF5 external link to "),
    (relative_soft_chain_to_external, "/data/demo_02/right_pressure -> /data/demo_02/hop -> /data/demo_02/ext: "
                                      "an HDF5 external link to "),
    (dangling, "/data/demo_02/right_pressure: a soft link to /nowhere/p, which names nothing in the file "
               "(dangling)"),
    (loop, "/data/demo_02/right_pressure: more than 16 soft links on the way"),
    (dangling_clip, "/data/demo_02: a soft link to /gone, which names nothing in the file (dangling)"),
])
def test_soft_links_leaving_the_file_or_naming_nothing_fail_their_clip_only(tmp_path, capsys, how, said):
    raw = make_opentouch(tmp_path / "raw")
    with h5py.File(raw / SCENE, "r+") as f:
        how(f, f["data/demo_02"], tmp_path / "outside.h5")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if "demo_02" in line]
    assert len(err) == 1 and f"{SCENE} [ot-home_kitchen_p1-demo_02]: {said}" in err[0], err
    assert "Traceback" not in err[0] and "KeyError" not in err[0]
    assert sorted(e["episode_id"] for e in load_episodes(out)) == OTHERS


def test_a_soft_link_inside_the_file_is_followed(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    with h5py.File(raw / SCENE, "r+") as f:
        g = f["data/demo_02"]
        f.move("data/demo_02/right_pressure", "kept/pressure")
        g["right_pressure"] = h5py.SoftLink("/kept/pressure")
        f.move("data/demo_02/timestamps", "kept/timestamps")
        f["data/alias"] = h5py.SoftLink("demo_02")                 # relative, then through the alias
        g["timestamps"] = h5py.SoftLink("/data/alias/./stamps")
        f["data/demo_02/stamps"] = h5py.SoftLink("/kept/timestamps")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 0
    assert sorted(e["episode_id"] for e in load_episodes(out)) == sorted(OTHERS + ["ot-home_kitchen_p1-demo_02"])
