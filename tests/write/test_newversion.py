"""The new-version transaction (htdata/write/newversion.py): lock -> parent -> units -> commit, or clean up.

The writers (rm, trim, merge, split, renormalise, ingest) reach it through their commands (tests/curate/,
tests/ingest/, tests/store/test_lifecycle_faults.py); here it is driven directly: what a failure leaves,
what a plan-only use (a dry-run) touches, a resumable writer, a failure after the commit's link.
"""

import os

import pytest

from htdata.errors import DatasetError
from htdata.format.table import MANIFEST_FILE, SHARDS_DIR
from htdata.store import versions
from htdata.store.lock import LOCK_FILE, DatasetLocked, WriterLock
from htdata.store.versions import list_versions
from htdata.write.newversion import NewVersion
from htdata.write.repack import KeptEpisode, samples_per_shard_of
from tests.factories import MIXED_HANDS_EPISODES, mixed_hands_coverages, write_synthetic_dataset


@pytest.fixture
def dataset(tmp_path):
    return write_synthetic_dataset(tmp_path / "ds", MIXED_HANDS_EPISODES, coverages=mixed_hands_coverages())


def shard_files(root):
    return sorted(p.name for p in (root / SHARDS_DIR).iterdir())


def repack_first_part(nv: NewVersion):
    part = nv.parent.parts()[0]
    kept = [KeptEpisode(e, range(int(e["num_frames"]))) for e in part.episodes]
    return part, nv.repack(nv.reader(), kept, samples_per_shard_of(part))


class Boom(Exception):
    pass


@pytest.mark.parametrize("failure", [Boom, KeyboardInterrupt])
def test_a_failure_before_the_commit_leaves_the_dataset_as_it_was(dataset, failure):
    before, pointer = shard_files(dataset), (dataset / MANIFEST_FILE).read_bytes()
    with pytest.raises(failure):
        with NewVersion(dataset, "test") as nv:
            _, new = repack_first_part(nv)
            assert all((dataset / SHARDS_DIR / s["name"]).is_file() for s in new.shards)
            raise failure()
    assert shard_files(dataset) == before and (dataset / MANIFEST_FILE).read_bytes() == pointer
    assert list_versions(dataset) == [1] and not (dataset / LOCK_FILE).exists()


def test_the_commit_numbers_units_from_the_parent_and_records_the_next_free_one(dataset):
    with NewVersion(dataset, "test") as nv:
        first = nv.first_unit
        assert first == nv.parent.next_unit()
        old, new = repack_first_part(nv)
        manifest = nv.commit([new] + nv.parent.parts()[1:])
    assert new.unit == first and manifest["version"] == 2 and manifest["next_unit"] == first + 1
    assert manifest["change"]["command"] == "test"


def test_the_first_write_clears_an_interrupted_writes_shards_and_a_plan_touches_nothing(dataset):
    with NewVersion(dataset, "probe") as nv:
        left = f"shard-{nv.first_unit + 2:06d}-000.tar"
    (dataset / SHARDS_DIR / left).write_bytes(b"interrupted")
    with NewVersion(dataset, "dry run") as nv:     # plans only (a --dry-run): nothing is written or deleted
        nv.reader().sample(0)
    assert left in shard_files(dataset)
    with NewVersion(dataset, "split", new_units=False) as nv:   # the parent's parts as they are: no unit
        with pytest.raises(ValueError, match="new_units=False"):
            nv.take_unit()
        nv.commit(nv.parent.parts())
    assert left in shard_files(dataset) and list_versions(dataset) == [1, 2]
    with NewVersion(dataset, "rm") as nv:
        nv.take_unit()
    assert left not in shard_files(dataset)


def test_a_resumable_write_keeps_its_units_when_it_fails(dataset):
    with pytest.raises(Boom):
        with NewVersion(dataset, "ingest", parent="optional", resumable=True) as nv:
            _, new = repack_first_part(nv)
            raise Boom()
    assert all((dataset / SHARDS_DIR / s["name"]).is_file() for s in new.shards)


def test_a_failure_after_the_version_file_is_linked_deletes_nothing(dataset, monkeypatch):
    """The version file is the commit: a failure writing dataset.json (its cache) after it leaves the units."""
    real = versions.write_bytes_atomic

    def pointer_fails(path, data):
        if os.path.basename(path) == MANIFEST_FILE:
            raise DatasetError("disk gone")
        return real(path, data)

    monkeypatch.setattr(versions, "write_bytes_atomic", pointer_fails)
    with pytest.raises(DatasetError, match="disk gone"):
        with NewVersion(dataset, "rm") as nv:
            old, new = repack_first_part(nv)
            nv.commit([new] + nv.parent.parts()[1:])
    assert list_versions(dataset) == [1, 2]
    assert all((dataset / SHARDS_DIR / s["name"]).is_file() for s in new.shards)


def test_a_new_dataset_has_no_parent_and_units_from_zero_or_where_asked(tmp_path, dataset):
    with NewVersion(tmp_path / "fresh", "ingest", parent="optional", resumable=True) as nv:
        assert nv.parent is None and nv.first_unit == 0
        with pytest.raises(ValueError, match="no parent version"):
            nv.reader()
    with NewVersion(tmp_path / "out", "merge", parent="none", first_unit=7, resumable=True) as nv:
        assert nv.parent is None and nv.take_unit() == 7 and nv.unit == 8
    with NewVersion(dataset, "append", parent="optional") as nv:
        assert nv.parent.version == 1


def test_the_lock_is_taken_first_and_a_missing_dataset_releases_it(tmp_path, dataset):
    with WriterLock(dataset, "other writer"):
        with pytest.raises(DatasetLocked, match="other writer"):
            with NewVersion(dataset, "rm"):
                pass
    empty = tmp_path / "empty"
    with pytest.raises(FileNotFoundError):
        with NewVersion(empty, "rm"):
            pass
    assert not (empty / LOCK_FILE).exists()


def test_carry_or_repack_walks_the_parents_parts_in_order(dataset, tmp_path):
    """The one walk over a version's parts: each part carried, re-packed into a new unit, or left out."""
    with NewVersion(dataset, "test") as nv:
        parts = nv.parent.parts()
        assert len(parts) == 2
        before = shard_files(dataset)
        carried = nv.carry_or_repack(lambda p: p)
        assert [(p.unit, p.episode_ids) for p in carried] == [(p.unit, p.episode_ids) for p in parts]
        assert shard_files(dataset) == before                  # carrying writes nothing
        walked = nv.carry_or_repack(lambda p: [KeptEpisode.whole(e) for e in p.episodes] if p.unit == parts[1].unit
                                    else None)
        nv.commit(walked)
    assert len(walked) == 1 and walked[0].unit == nv.first_unit
    assert walked[0].episode_ids == parts[1].episode_ids and walked[0].rows == parts[1].rows
    assert list_versions(dataset) == [1, 2]
    with NewVersion(tmp_path / "new", "test", parent="none") as nv:
        with pytest.raises(ValueError, match="no parent version to walk"):
            nv.carry_or_repack(lambda p: p)
