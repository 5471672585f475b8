"""A stranger's stats/ cache is read no further than its shape: a hostile entry is recomputed, never walked."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from htdata.inspect import stats
from htdata.inspect.statscache import read_entry, well_formed
from tests.factories.tactile import LEFT, RIGHT, clean_series, write_taxel_dataset

HTDATA = Path(sys.executable).with_name("htdata")
DEEP = "[" * 200_000 + "]" * 200_000          # json.loads: RecursionError (was a traceback in five commands)


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    root = write_taxel_dataset(tmp_path_factory.mktemp("cache") / "ds", [
        {"episode_id": f"ep_{k}", "task": "pour", "scene": "lab",
         "hands": {"right": (RIGHT, clean_series(RIGHT, 20, seed=k)), "left": (LEFT, clean_series(LEFT, 20, seed=k))}}
        for k in range(2)])
    stats.dataset_stats(root)                 # fills DATASET/stats/
    return root


def test_every_entry_the_project_writes_is_well_formed(ds):
    entries = sorted((ds / stats.STATS_DIR).glob("*.json"))
    assert len(entries) == 2
    assert all(well_formed(json.loads(p.read_text())) and read_entry(p) is not None for p in entries)


@pytest.mark.parametrize("bad", [
    {"episode_id": "ep", "frames": 3, "hands": {"right": {"layout": "x", "frames": 3, "hist": [[[1]]]}}},
    {"episode_id": "ep", "frames": 3, "hands": {"right": {"layout": "x", "frames": 3, "regions": {"a": {"b": {}}}}}},
    {"episode_id": "ep", "frames": 3, "hands": {"right": {"layout": "x", "frames": 3, "health": {"cells": {"dead": [[1, 2, 3]]}}}}},
    {"episode_id": "ep", "frames": -1, "hands": {}},
    {"episode_id": 7, "frames": 3, "hands": {}},
    [1, 2, 3],
    {"episode_id": "ep", "frames": 3, "hands": {"right": {"layout": "x", "frames": 3, "frame_max": ["a"]}}},
])
def test_entries_of_another_shape_are_not_trusted(bad, tmp_path):
    path = tmp_path / "e.json"
    path.write_text(json.dumps(bad))
    assert read_entry(path) is None


def test_commands_recompute_a_deeply_nested_cache_without_a_traceback(ds, tmp_path):
    for entry in (ds / stats.STATS_DIR).glob("*.json"):
        entry.write_text(DEEP)
    runs = {"stats": ["stats", str(ds), "--brief"], "validate": ["validate", str(ds)],
            "card": ["card", str(ds), str(tmp_path / "card.html")],
            "preview": ["preview", str(ds), str(tmp_path / "p.png")],
            "view": ["view", str(ds), "--save", str(tmp_path / "v.rrd")]}
    for name, args in runs.items():
        if name == "view" and subprocess.run([sys.executable, "-c", "import rerun"]).returncode:
            continue                                           # rerun-sdk is an extra
        done = subprocess.run([str(HTDATA), *args], capture_output=True, text=True, timeout=300)
        assert "Traceback" not in done.stderr and "RecursionError" not in done.stderr, (name, done.stderr[-2000:])
        assert done.returncode == 0, (name, done.returncode, done.stderr[-2000:])
