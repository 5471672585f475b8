"""Format 4: a version's records as shared immutable segments (htdata/store/segments.py).

The reference each test holds a segmented version against is one the segments did not make: the
same dataset rewritten as format 3 (tests/factories/legacy.py), whose records and samples the
format 3 readers serve, and the bytes on disk before and after a write.
"""

import hashlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from htdata.curate.edit import remove_episodes
from htdata.curate.gc import collect
from htdata.curate.upgrade import upgrade
from htdata.errors import DatasetError
from htdata.format.table import MANIFEST_FILE, SEGMENTS_DIR
from htdata.read.reader import DatasetReader
from htdata.store import segments, storage
from htdata.store.confine import PathOutsideDataset
from htdata.store.manifest import load_manifest
from htdata.store.versions import list_versions, version_manifest_file
from htdata.validate import validate_dataset
from tests.factories import write_synthetic_dataset
from tests.factories.legacy import as_format3

EPISODES = [{"episode_id": f"ep_{i:02d}", "task": "pour" if i % 3 else "wipe", "scene": "lab",
             "hands": ("right",) if i % 2 else ("left", "right"), "num_frames": 2 + i % 4} for i in range(12)]


@pytest.fixture
def small_segments(monkeypatch):
    """Segments of 4 units, so that 12 one-episode units make 3 of them."""
    monkeypatch.setattr(segments, "SEGMENT_UNITS", 4)


def _dataset(root):
    return write_synthetic_dataset(root, EPISODES, episodes_per_unit=1, samples_per_shard=3)


def _segment_files(root):
    folder = root / SEGMENTS_DIR
    return {p.name: p.stat().st_size for p in folder.iterdir()} if folder.is_dir() else {}


def _same_version(a, b, version):
    with DatasetReader(a, version=version) as ra, DatasetReader(b, version=version) as rb:
        assert ra.manifest["shards"] == rb.manifest["shards"]
        assert ra.episodes == rb.episodes
        assert np.array_equal(np.asarray(ra.index), np.asarray(rb.index))
        for i in range(len(ra)):
            assert ra.sample(i) == rb.sample(i)      # every member's bytes


def test_a_segmented_version_reads_exactly_as_its_format3_copy(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    remove_episodes(root, ["ep_05"], dry_run=False, command="rm")
    stored = load_manifest(root)
    assert stored["format_version"] == 4 and "shards" not in stored and "index_file" not in stored
    assert [s["units"] for s in stored["segments"]] == [4, 3, 4]     # ep_05 was all of unit 5: dropped whole
    legacy = as_format3(shutil.copytree(root, tmp_path / "v3"))
    assert load_manifest(legacy)["format_version"] == 3 and not (legacy / SEGMENTS_DIR).exists()
    for version in (1, 2):
        _same_version(root, legacy, version)
    assert validate_dataset(root, deep=True)["ok"] and validate_dataset(legacy, deep=True)["ok"]


def test_a_one_episode_rm_writes_only_the_segment_it_changes(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    before = _segment_files(root)
    first = load_manifest(root)["segments"]
    remove_episodes(root, ["ep_05"], dry_run=False, command="rm")
    after = load_manifest(root)["segments"]
    new = {name: size for name, size in _segment_files(root).items() if name not in before}
    # units 4-7 hold ep_05: that segment is written again (its unit re-packed), the other two are shared
    assert [e["records"] for e in after][0::2] == [e["records"] for e in first][0::2]
    assert after[1]["records"] != first[1]["records"] and len(new) == 2
    assert sum(new.values()) < sum(before.values()) / 2
    with DatasetReader(root, version=1) as old:   # the old version still reads, from its own segments
        assert "ep_05" in [e["episode_id"] for e in old.episodes] and len(old) == sum(e["num_frames"] for e in EPISODES)


def test_a_damaged_or_missing_segment_is_named_by_the_reader_and_by_validate(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    entry = load_manifest(root)["segments"][1]
    path = root / entry["index"]
    data = bytearray(path.read_bytes())
    data[-3] ^= 0xFF                      # one byte of an index row
    path.write_bytes(bytes(data))
    with DatasetReader(root) as reader, pytest.raises(DatasetError, match=entry["index"].split("/")[1]):
        reader.index
    report = validate_dataset(root)
    assert not report["ok"] and report["checks"]["structure"]["failure_count"]
    assert any(f["what"] == "segment_damaged" for f in report["checks"]["structure"]["failures"])
    (root / entry["records"]).unlink()
    with pytest.raises(FileNotFoundError, match="segment file listed by"):
        DatasetReader(root)


def _forge(root, mutate):
    """Change segment 0's records and record their new sha256 in every manifest, as a forger would."""
    manifest = load_manifest(root)
    entry = manifest["segments"][0]
    doc = json.loads((root / entry["records"]).read_bytes())
    mutate(doc)
    data = json.dumps(doc).encode()
    (root / entry["records"]).write_bytes(data)
    entry["records_sha256"] = hashlib.sha256(data).hexdigest()
    text = json.dumps(manifest, indent=2) + "\n"
    (root / MANIFEST_FILE).write_text(text)
    (root / version_manifest_file(manifest["version"])).write_text(text)


def test_a_segment_naming_a_shard_outside_the_dataset_is_refused(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    _forge(root, lambda doc: doc["units"][0]["shards"][0].update(name="../../etc/shard-000000-000.tar"))
    with pytest.raises(PathOutsideDataset):
        DatasetReader(root)


def test_a_segment_path_that_climbs_out_of_the_dataset_is_refused(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    manifest = load_manifest(root)
    outside = tmp_path / "payload.json"
    shutil.copy(root / manifest["segments"][0]["records"], outside)
    manifest["segments"][0]["records"] = "../payload.json"
    (root / version_manifest_file(manifest["version"])).write_text(json.dumps(manifest))
    with pytest.raises(PathOutsideDataset, match=r"segments\[0\]\.records"):
        DatasetReader(root, validate_manifest=False)


def test_a_large_index_is_assembled_once_into_the_cache_and_mapped(tmp_path, small_segments, monkeypatch):
    root = _dataset(tmp_path / "ds")
    with DatasetReader(root) as reader:
        in_memory = np.array(reader.index)
    monkeypatch.setenv(storage.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(segments, "INDEX_CACHE_MIN_BYTES", 0)
    with DatasetReader(root) as reader:
        mapped = reader.index
        assert isinstance(mapped, np.memmap) and np.array_equal(np.asarray(mapped), in_memory)
    cached = next((tmp_path / "cache" / "index").rglob("index.npy"))
    stamp = cached.stat().st_mtime_ns
    with DatasetReader(root) as reader:
        assert np.array_equal(np.asarray(reader.index), in_memory)
    assert cached.stat().st_mtime_ns == stamp        # the second open assembles nothing
    manifest = load_manifest(root)
    manifest["index_sha256"] = "0" * 64              # a manifest the segments do not match
    with pytest.raises(DatasetError, match="index assembled from"):
        segments.load_segment_index(root, manifest)


def test_upgrade_moves_a_format3_dataset_and_keeps_what_it_holds(tmp_path, small_segments):
    root = as_format3(_dataset(tmp_path / "ds"))
    plan, manifest = upgrade(root, dry_run=True, command="htdata upgrade")
    assert plan.needed and manifest is None and list_versions(root) == [1]
    plan, manifest = upgrade(root, dry_run=False, command="htdata upgrade")
    assert manifest["version"] == 2 and manifest["format_version"] == 4 and list_versions(root) == [1, 2]
    copy = shutil.copytree(root, tmp_path / "copy")
    with DatasetReader(root, version=1) as v1, DatasetReader(copy, version=2) as v2:
        assert v1.episodes == v2.episodes and np.array_equal(np.asarray(v1.index), np.asarray(v2.index))
        assert v1.manifest["shards"] == v2.manifest["shards"]
    plan, manifest = upgrade(root, dry_run=False, command="htdata upgrade")
    assert not plan.needed and manifest is None and list_versions(root) == [1, 2]
    out = subprocess.run([sys.executable, "-m", "htdata.cli", "upgrade", str(root), "--dry-run"],
                         capture_output=True, text=True)
    assert out.returncode == 0 and "format 4 already" in out.stdout


def test_gc_deletes_the_segments_no_kept_version_lists_and_keeps_shared_ones(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    v1 = {e[k] for e in load_manifest(root)["segments"] for k in ("records", "index")}
    remove_episodes(root, ["ep_05"], dry_run=False, command="rm")
    v2 = {e[k] for e in load_manifest(root)["segments"] for k in ("records", "index")}
    plan = collect(root, keep_versions=1, dry_run=True, command="gc", retention_s=0, force=True)
    assert {f"{SEGMENTS_DIR}/{n}" for n, _ in plan.dropped_segments} == v1 - v2
    collect(root, keep_versions=1, dry_run=False, command="gc", retention_s=0, force=True)
    assert {f"{SEGMENTS_DIR}/{n}" for n in os.listdir(root / SEGMENTS_DIR)} == v2
    assert validate_dataset(root, deep=True)["ok"]


def test_a_symlinked_segments_folder_is_refused_before_anything_is_written(tmp_path, small_segments):
    root = _dataset(tmp_path / "ds")
    elsewhere = tmp_path / "elsewhere"
    (root / SEGMENTS_DIR).rename(elsewhere)
    (root / SEGMENTS_DIR).symlink_to(elsewhere)
    before = sorted(os.listdir(elsewhere))
    with pytest.raises(DatasetError, match="is a symlink"):
        remove_episodes(root, ["ep_05"], dry_run=False, command="rm")
    assert sorted(os.listdir(elsewhere)) == before and list_versions(root) == [1]


def test_validate_reads_every_segment_even_when_the_assembled_index_is_cached(tmp_path, small_segments, monkeypatch):
    root = _dataset(tmp_path / "ds")
    monkeypatch.setenv(storage.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(segments, "INDEX_CACHE_MIN_BYTES", 0)
    with DatasetReader(root) as reader:
        reader.index                          # the assembled index is now in the cache
    entry = load_manifest(root)["segments"][2]
    path = root / entry["index"]
    data = bytearray(path.read_bytes())
    data[-5] ^= 0xFF
    path.write_bytes(bytes(data))
    report = validate_dataset(root)
    assert any(f["what"] == "segment_damaged" and entry["index"].split("/")[1] in f["message"]
               for f in report["checks"]["structure"]["failures"])
