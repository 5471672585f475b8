"""htdata trim --idle: head and tail without contact go, in one new version; nothing else changes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from htdata.cli import main as cli_main
from htdata.curate import idle
from htdata.inspect import stats
from htdata.read.reader import DatasetReader
from tests.factories.tactile import LEFT, RIGHT, write_taxel_dataset

N = 40


def _pressed(frames: range, n: int = N, value: float = 0.5, shape=(16, 16), cell=(0, 0)) -> np.ndarray:
    g = np.zeros((n, *shape), np.float32)
    g[list(frames), cell[0], cell[1]] = value
    return g


def _stats(frames: int, hands: dict) -> dict:
    """A stats entry with given per-frame maxima: {hand: (frame_index, frame_max)}."""
    return {"frames": frames, "hands": {h: {"frame_index": list(i), "frame_max": list(m)} for h, (i, m) in hands.items()}}


def test_plan_cut_keeps_contact_plus_margin_on_any_hand():
    cfg = idle.IdleConfig(min_contact=0.02, keep_margin_s=0.5)
    rec = {"episode_id": "e", "fps": 10.0}
    right = np.zeros(N)
    right[10:20] = 0.4
    left = np.zeros(N)
    left[22] = 0.03                                    # the other hand's contact counts too
    cut = idle.plan_cut(rec, _stats(N, {"right": (range(N), right), "left": (range(N), left)}), cfg)
    assert cut.keep == range(5, 28) and cut.dropped == N - 23
    assert "would drop 5 head + 12 tail" in cut.line(dry_run=True)
    assert idle.plan_cut(rec, _stats(N, {"right": (range(N), right)}), idle.IdleConfig(0.5, 0.5)).keep is None
    near_edges = np.zeros(N)
    near_edges[[3, N - 2]] = 1.0
    assert idle.plan_cut(rec, _stats(N, {"right": (range(N), near_edges)}), cfg).keep is None


def test_unreadable_frames_count_as_contact():
    maxima = np.zeros(N - 1)
    maxima[20] = 0.5
    frames = [f for f in range(N) if f != 2]           # frame 2's map held NaN: not in frame_index
    cut = idle.plan_cut({"episode_id": "e", "fps": 10.0}, _stats(N, {"right": (frames, maxima)}),
                        idle.IdleConfig(keep_margin_s=0.0))
    assert cut.keep == range(2, 22)


def test_config_is_validated():
    with pytest.raises(ValueError, match="--keep-margin"):
        idle.IdleConfig(keep_margin_s=-1).validate()
    with pytest.raises(ValueError, match="--min-contact"):
        idle.IdleConfig(min_contact=1.5).validate()


@pytest.fixture()
def ds(tmp_path):
    return write_taxel_dataset(tmp_path / "ds", [
        {"episode_id": "ep_a", "fps": 10.0, "hands": {"right": (RIGHT, _pressed(range(15, 25)))}},
        {"episode_id": "ep_b", "fps": 10.0, "hands": {"right": (RIGHT, np.zeros((12, 16, 16), np.float32))}},
        {"episode_id": "ep_c", "fps": 10.0, "hands": {"left": (LEFT, _pressed(range(0, N), shape=(21, 21), cell=(2, 1)))}},
    ], samples_per_shard=8)


def test_dry_run_lists_and_writes_nothing(ds, capsys):
    assert cli_main(["trim", str(ds), "--idle", "--keep-margin", "0.3", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "episode ep_a: would drop 12 head + 12 tail idle frames, keep 12:28 of 40" in out
    assert "episode ep_b: no contact by its contact rule in any of its 12 frames" in out
    assert "episode ep_c: no idle head or tail beyond the margin" in out
    assert "24 frames would be removed" in out
    assert json.loads((ds / "dataset.json").read_text())["version"] == 1


def test_trim_writes_one_version_and_stats_recompute_only_the_trimmed_episode(ds, capsys):
    stats.dataset_stats(ds)                                 # cache version 1
    with DatasetReader(ds) as r:
        before = [r.decoded(r.locate("ep_a", f))["tactile"]["right"] for f in range(12, 28)]
    assert cli_main(["trim", str(ds), "--idle", "--keep-margin", "0.3"]) == 0
    assert "version 2 (parent 1)" in capsys.readouterr().out
    with DatasetReader(ds) as r:
        assert r.version == 2
        eps = {e["episode_id"]: e for e in r.episodes}
        assert eps["ep_a"]["num_frames"] == 16 and eps["ep_a"]["trimmed"] == {"start": 12, "stop": 28, "of": N}
        assert eps["ep_b"]["num_frames"] == 12 and "trimmed" not in eps["ep_b"]
        after = [r.decoded(r.locate("ep_a", f))["tactile"]["right"] for f in range(16)]
    assert all(np.array_equal(a, b) for a, b in zip(before, after))
    s = stats.dataset_stats(ds)
    assert s["cache"]["computed"] == 1 and s["cache"]["cached"] == 2
    # trimming again finds nothing idle and writes no version
    assert cli_main(["trim", str(ds), "--idle", "--keep-margin", "0.3"]) == 0
    assert "nothing changed: version 2 stays current" in capsys.readouterr().out
    assert json.loads((ds / "dataset.json").read_text())["version"] == 2


def test_cli_refuses_mixed_modes(ds, capsys):
    assert cli_main(["trim", str(ds), "ep_a", "--idle"]) == 2
    assert "--idle trims every episode" in capsys.readouterr().err
    assert cli_main(["trim", str(ds), "ep_a"]) == 2
    assert cli_main(["trim", str(ds), "--idle", "--keep-margin", "-1"]) == 2
    assert "--keep-margin" in capsys.readouterr().err


def test_many_shards_are_summed_up_in_one_line(tmp_path, capsys):
    # five episodes over many small shards: the plan names the shards in one summary line, not one line each
    eps = [{"episode_id": f"ep_{k}", "fps": 10.0, "hands": {"right": (RIGHT, _pressed(range(15, 25)))}}
           for k in range(5)]
    root = write_taxel_dataset(tmp_path / "many", eps, samples_per_shard=8)
    assert cli_main(["trim", str(root), "--idle", "--keep-margin", "0.3", "--dry-run"]) == 0
    out = capsys.readouterr().out.splitlines()
    shard_lines = [line for line in out if "stop listing" in line]
    assert len(shard_lines) == 1 and "would stop listing 25 shards (" in shard_lines[0]
    assert sum("re-pack" in line for line in out) == 1 and "would re-pack 5 work units (0 .. 4;" in "\n".join(out)
