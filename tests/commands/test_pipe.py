"""A reader that stops early (`htdata log | head -1`): the command ends quietly, no traceback.

The pipe's read end is closed before the command writes, so every write meets EPIPE: the case
`head` produces by exiting after its first line, made deterministic.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.factories import commit_split
from tests.factories.tactile import RIGHT, clean_series, write_taxel_dataset

HTDATA = Path(sys.executable).with_name("htdata")


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    root = write_taxel_dataset(tmp_path_factory.mktemp("pipe") / "ds", [
        {"episode_id": f"ep_{k}", "task": task, "scene": "kitchen", "hands": {"right": (RIGHT, clean_series(RIGHT, 20, seed=k))}}
        for k, task in enumerate(["pour", "wipe", "pour"])])
    commit_split(root, "main", {"train": ["ep_0", "ep_1"], "test": ["ep_2"]})
    return root


@pytest.mark.parametrize("args", [["log"], ["stats"], ["split", "--list-tasks"], ["log", "--json"]])
def test_a_closed_pipe_ends_the_command_quietly(ds, args):
    proc = subprocess.Popen([str(HTDATA), args[0], str(ds), *args[1:]], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.stdout.close()          # the reader is gone before the first line
    err = proc.stderr.read()
    rc = proc.wait(120)
    assert "Traceback" not in err and "BrokenPipe" not in err and "Broken pipe" not in err, err
    assert rc in (0, 141), (rc, err)
