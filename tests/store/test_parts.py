"""`part_from_rows`: the commit takes a unit's index rows back as an array, checked without a loop per sample."""

import json

import numpy as np
import pytest

from htdata.errors import DatasetError
from htdata.format.shardio import ShardWriter, sample_key
from htdata.store.manifest import UnitResult
from htdata.store.parts import assemble, part_from_rows, part_from_unit


def two_episode_unit(tmp_path, unit=3):
    """Unit `unit`: episode a (5 frames) then b (3 frames), two samples a shard (a spans three shards)."""
    with ShardWriter(tmp_path, unit=unit, samples_per_shard=2) as w:
        for eid, n in (("a", 5), ("b", 3)):
            for f in range(n):
                key = sample_key(eid, f)
                w.add_sample(key, {"json": json.dumps({"key": key}).encode(), "rgb.jpg": b"x" * (f + 1)})
    episodes = [{"episode_id": "a", "num_frames": 5}, {"episode_id": "b"}]
    return UnitResult(unit=unit, shards=w.shards, samples=w.samples, episodes=episodes)


def test_rows_made_where_the_unit_ran_give_the_same_part_as_its_samples(tmp_path):
    unit = two_episode_unit(tmp_path)
    made = part_from_unit(unit)
    shards = [{"name": s.name, "sha256": s.sha256, "bytes": s.bytes, "samples": s.samples} for s in unit.shards]
    back = part_from_rows(unit.unit, shards, made.rows.copy(), [dict(e) for e in unit.episodes])
    assert back.unit == made.unit and back.shards == made.shards and back.episodes == made.episodes
    assert back.rows.tobytes() == made.rows.tobytes()
    assert [e["num_frames"] for e in back.episodes] == [5, 3]
    assert assemble([back]).rows.tobytes() == assemble([made]).rows.tobytes()
    empty = part_from_rows(9, [], made.rows[:0], [])        # a unit whose episode failed: nothing
    assert len(empty.rows) == 0 and empty.episodes == []


def _broken(rows, column, index, value):
    out = rows.copy()
    out[column][index] = value
    return out


def test_rows_that_do_not_fit_their_unit_are_refused_naming_it(tmp_path):
    unit = two_episode_unit(tmp_path)
    rows = part_from_unit(unit).rows
    shards = [{"name": s.name, "sha256": s.sha256, "bytes": s.bytes, "samples": s.samples} for s in unit.shards]
    eps = [dict(e) for e in unit.episodes]
    cases = {
        "expected frame 2, got 3": _broken(rows, "frame", 2, 3),                  # a frame skipped
        "episode\\(s\\) in order": _broken(rows, "episode", 1, 1),                 # a interrupted by b
        "2 episode": _broken(rows, "episode", 7, 2),                              # an episode that is not there
        "shard\\(s\\) in order": _broken(rows, "shard", 0, 1),
        "offsets do not rise": _broken(rows, "offset", 1, 0),
        "num_frames=5": np.concatenate([rows[:4], rows[5:]]),                     # a record says more frames
    }
    for message, bad in cases.items():
        with pytest.raises(DatasetError, match=f"unit 3: .*{message}"):
            part_from_rows(3, shards, bad, [dict(e) for e in eps])
    with pytest.raises(DatasetError, match="unit 3: episode record.*without samples"):
        part_from_rows(3, shards, rows[:0], eps)
    with pytest.raises(DatasetError, match="dtype"):
        part_from_rows(3, shards, np.zeros(8, [("shard", "<u4")]), eps)
