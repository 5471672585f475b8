"""Re-packing committed samples into new shards (htdata/write/repack.py), the layer both writers share.

rm / trim / merge / renormalise and an append's reused episodes reach it through their commands
(tests/curate/, tests/ingest/); here it is driven directly: members copied byte for byte, a trimmed
episode renumbered (its json member only), the rewrite hook, clearing an interrupted write's shards.
"""

import json
import tarfile
from pathlib import Path

import pytest

from htdata.format.shardio import sample_key
from htdata.format.table import SHARDS_DIR
from htdata.read.reader import DatasetReader
from htdata.store.parts import Part
from htdata.write.repack import KeptEpisode, clear_uncommitted, repack_unit, samples_per_shard_of
from tests.factories import MIXED_HANDS_EPISODES, mixed_hands_coverages, write_synthetic_dataset


@pytest.fixture
def dataset(tmp_path):
    return write_synthetic_dataset(tmp_path / "ds", MIXED_HANDS_EPISODES, coverages=mixed_hands_coverages())


def shard_samples(root: Path, part: Part) -> dict[str, dict[str, bytes]]:
    """{key: {suffix: bytes}} of every sample in the part's shards, read with tarfile (any tar reader)."""
    out: dict[str, dict[str, bytes]] = {}
    for shard in part.shards:
        with tarfile.open(root / SHARDS_DIR / shard["name"]) as tar:
            for m in tar.getmembers():
                key, suffix = m.name.split(".", 1)
                out.setdefault(key, {})[suffix] = tar.extractfile(m).read()
    return out


def record(reader: DatasetReader, episode_id: str) -> dict:
    return next(e for e in reader.episodes if e["episode_id"] == episode_id)


def test_whole_episodes_are_copied_byte_for_byte_into_the_new_unit(dataset):
    reader = DatasetReader(dataset)
    unit = int(reader.manifest["next_unit"])
    kept = [KeptEpisode(record(reader, e), range(record(reader, e)["num_frames"])) for e in ("ep_a", "ep_b")]
    part = repack_unit(reader, kept, unit, samples_per_shard=3)
    assert part.unit == unit and part.episode_ids == ["ep_a", "ep_b"] and len(part.rows) == 5 + 4
    assert [s["name"] for s in part.shards] == [f"shard-{unit:06d}-{k:03d}.tar" for k in range(3)]
    assert [s["samples"] for s in part.shards] == [3, 3, 3] and samples_per_shard_of(part) == 3
    written = shard_samples(dataset, part)
    for eid in ("ep_a", "ep_b"):
        first, n = reader.episode_range(eid)
        for f in range(n):
            assert written[sample_key(eid, f)] == reader.sample(first + f)     # every member, every byte
    assert [e["num_frames"] for e in part.episodes] == [5, 4]


def test_a_trimmed_episode_is_renumbered_and_only_its_json_member_changes(dataset):
    reader = DatasetReader(dataset)
    first, _ = reader.episode_range("ep_a")
    part = repack_unit(reader, [KeptEpisode(record(reader, "ep_a"), range(1, 4))], 9, samples_per_shard=8)
    written = shard_samples(dataset, part)
    assert sorted(written) == [sample_key("ep_a", k) for k in range(3)] and part.episodes[0]["num_frames"] == 3
    for new, old in enumerate(range(1, 4)):
        source, copy = reader.sample(first + old), written[sample_key("ep_a", new)]
        assert {k: v for k, v in copy.items() if k != "json"} == {k: v for k, v in source.items() if k != "json"}
        meta, was = json.loads(copy["json"]), json.loads(source["json"])
        assert (meta["key"], meta["frame_index"]) == (sample_key("ep_a", new), new)
        assert {k: v for k, v in meta.items() if k not in ("key", "frame_index")} == \
            {k: v for k, v in was.items() if k not in ("key", "frame_index")}


def test_the_rewrite_hook_sees_every_sample_and_record(dataset):
    reader = DatasetReader(dataset)
    seen = []

    class Mark:
        def members(self, episode_id, frame, members):
            seen.append((episode_id, frame))
            return {**members, "json": json.dumps({**json.loads(members["json"]), "marked": True}).encode()}

        def record(self, rec):
            return {**rec, "notes": ["marked"]}

    part = repack_unit(reader, [KeptEpisode(record(reader, "ep_b"), range(4))], 7, 4, rewrite=Mark())
    assert seen == [("ep_b", f) for f in range(4)] and part.episodes[0]["notes"] == ["marked"]
    assert all(json.loads(m["json"])["marked"] for m in shard_samples(dataset, part).values())


def test_a_frame_outside_the_episode_is_refused_and_no_shard_is_left(dataset):
    reader = DatasetReader(dataset)
    with pytest.raises(ValueError, match=r"episode 'ep_c': frame 1 outside 0\.\.0"):
        repack_unit(reader, [KeptEpisode(record(reader, "ep_c"), range(0, 2))], 8, 4)
    assert not list((dataset / SHARDS_DIR).glob("*shard-000008-*"))


def test_clear_uncommitted_removes_only_the_shards_of_units_no_version_lists(dataset):
    shards = dataset / SHARDS_DIR
    committed = sorted(p.name for p in shards.iterdir())
    next_unit = int(DatasetReader(dataset).manifest["next_unit"])
    left = [f"shard-{next_unit:06d}-000.tar", f".shard-{next_unit:06d}-001.tar.tmp", f"shard-{next_unit + 3:06d}-000.tar"]
    for name in left + ["notes.txt"]:
        (shards / name).write_bytes(b"interrupted")
    assert sorted(clear_uncommitted(dataset, next_unit)) == sorted(left)
    assert sorted(p.name for p in shards.iterdir()) == sorted(committed + ["notes.txt"])
    assert clear_uncommitted(dataset, next_unit) == []


def test_samples_per_shard_of_a_part_is_its_largest_shard():
    import numpy as np

    assert samples_per_shard_of(Part(0, [{"samples": 2}, {"samples": 5}, {"samples": 1}], np.zeros(0), [])) == 5
    assert samples_per_shard_of(Part(0, [], np.zeros(0), [])) == 1
