"""DatasetMetadata: one version's records without its samples (htdata/read/metadata.py).

It reports what the reader did before it existed (the manifest, episodes and index files as
stored, coverage and region maps, split -> sample indices), never opens a shard, and a caller's
mistake is an ArgumentError (still the built-in type callers caught before).
"""

from __future__ import annotations

import hashlib
import json
import pickle
import shutil

import numpy as np
import pytest

import htdata
from htdata.errors import ArgumentError, DatasetError
from htdata.format.table import MANIFEST_FILE, SHARDS_DIR
from htdata.read.metadata import DatasetMetadata
from htdata.read.reader import DatasetReader
from tests.factories import (
    MIXED_HANDS_EPISODES,
    commit_split,
    default_canonical,
    mixed_hands_coverages,
    rewrite_manifest,
    write_synthetic_dataset,
)
from tests.factories.legacy import as_format3

EPISODES = MIXED_HANDS_EPISODES      # ep_a (R, 5 frames), ep_b (LR, 4), ep_c (L, 1)



@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("meta") / "ds"
    write_synthetic_dataset(root, EPISODES, seed=3, coverages=mixed_hands_coverages(), samples_per_shard=3)
    commit_split(root, "main", {"train": ["ep_c", "ep_a"], "val": ["ep_b"]})
    return root


@pytest.fixture
def copy(dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(dataset, out)
    return out


def stored_files(root):
    """A format 3 version's manifest, episodes and index, read straight from its files."""
    manifest = json.loads((root / MANIFEST_FILE).read_text())
    episodes = [json.loads(line) for line in (root / manifest["episodes_file"]).read_text().splitlines()]
    return manifest, episodes, np.load(root / manifest["index_file"])


FORMAT_FIELDS = ("format_version", "segments", "episodes_file", "index_file")   # where the records are kept


def test_metadata_reports_the_stored_records(dataset, tmp_path):
    # the reference: the same dataset rewritten as format 3, its files read without htdata's loaders
    manifest, episodes, index = stored_files(as_format3(shutil.copytree(dataset, tmp_path / "v3")))
    meta = DatasetMetadata(dataset)
    assert {k: v for k, v in meta.manifest.items() if k not in FORMAT_FIELDS} \
        == {k: v for k, v in manifest.items() if k not in FORMAT_FIELDS}
    assert meta.episodes == episodes and meta.version == manifest["version"] == 2
    assert np.array_equal(meta.index, index) and meta.num_samples == len(index) == 10
    assert meta.num_episodes == 3 and meta.episode_ids == ["ep_a", "ep_b", "ep_c"]
    assert meta.tasks == manifest["tasks"] and meta.scenes == manifest["scenes"]
    assert meta.hands == ("left", "right") and meta.layout_ids == ["glove_l", "glove_r"]
    assert meta.shard_names == [s["name"] for s in manifest["shards"]] and meta.codec == manifest["codec"]
    assert [meta.episode_range(e) for e in ("ep_a", "ep_b", "ep_c")] == [(0, 5), (5, 4), (9, 1)]
    assert meta.locate("ep_b", 2) == 7 and meta.episode_position(2) == 2
    for lid, cov in mixed_hands_coverages().items():
        assert np.array_equal(meta.coverage(lid), cov) and meta.layout(lid)["layout_id"] == lid
    assert np.array_equal(meta.region_map, default_canonical().part_map)
    assert np.array_equal(meta.place_map, default_canonical().region_map)
    older = DatasetMetadata(dataset, version=1)
    assert older.version == 1 and "main" not in older.manifest.get("splits", {}) and older.episodes == episodes


def test_the_reader_and_open_hand_on_their_metadata(dataset):
    reader = htdata.open(dataset)
    assert isinstance(reader.meta, DatasetMetadata)
    assert reader.manifest is reader.meta.manifest and reader.episodes is reader.meta.episodes
    assert reader.root == str(dataset) and reader.version == 2 and len(reader) == reader.meta.num_samples
    assert list(reader.sample_indices("main", "val")) == list(reader.meta.sample_indices("main", "val"))
    assert reader.locate.__doc__ == DatasetMetadata.locate.__doc__    # help() on the reader reads the same


def test_metadata_never_opens_a_shard(copy):
    (copy / SHARDS_DIR).rename(copy / "elsewhere")
    with pytest.raises(FileNotFoundError):
        DatasetReader(copy).sample(0)          # the shards are gone for a reader ...
    meta = DatasetMetadata(copy)               # ... and the metadata has all it needs without them
    assert len(meta.index) == 10 and meta.episode_range("ep_b") == (5, 4)
    assert np.array_equal(meta.coverage("glove_l"), mixed_hands_coverages()["glove_l"])
    assert set(meta.split("main")["parts"]) == {"train", "val"}
    assert list(meta.sample_indices("main", "train")) == [0, 1, 2, 3, 4, 9]


def test_split_selection(dataset):
    meta = DatasetMetadata(dataset)
    assert meta.episode_positions("main", "train") == [0, 2] and meta.episode_positions("main", "val") == [1]
    assert list(meta.sample_indices("main", "train")) == [0, 1, 2, 3, 4, 9]
    assert list(meta.sample_indices("main", "val")) == [5, 6, 7, 8]
    assert list(meta.sample_indices()) == list(range(10)) and meta.episode_positions() == [0, 1, 2]
    assert meta.sample_indices("main", "val").dtype == np.int64


def test_pickled_metadata_reloads_a_mapped_index_and_keeps_one_in_memory(dataset, tmp_path):
    meta = DatasetMetadata(dataset)        # format 4, a small index: assembled in memory from the segments
    before = np.array(meta.index)
    again = pickle.loads(pickle.dumps(meta))
    assert again._index is not None and np.array_equal(again.index, before)   # a worker does not assemble it again
    legacy = DatasetMetadata(as_format3(shutil.copytree(dataset, tmp_path / "v3")))
    assert isinstance(legacy.index, np.memmap)                                  # format 3's index.npy, mapped
    again = pickle.loads(pickle.dumps(legacy))
    assert again._index is None and np.array_equal(again.index, before)


@pytest.mark.parametrize("call, builtin, words", [
    (lambda m: m.split("nope"), FileNotFoundError, "no split named 'nope'"),
    (lambda m: m.sample_indices("main", "test"), KeyError, "no part 'test'"),
    (lambda m: m.sample_indices("main"), None, "choose a part"),
    (lambda m: m.sample_indices(None, "train"), None, "without a split"),
    (lambda m: m.episode_range("ep_x"), KeyError, "no episode 'ep_x'"),
    (lambda m: m.episode_range(3), IndexError, "out of range"),
    (lambda m: m.locate("ep_a", 5), IndexError, "frames 0..4"),
    (lambda m: m.coverage("glove_x"), KeyError, "glove_x"),
    (lambda m: m.layout("glove_x"), KeyError, "glove_x"),
])
def test_a_callers_mistake_is_an_argument_error(dataset, call, builtin, words):
    with pytest.raises(ArgumentError, match=words) as caught:
        call(DatasetMetadata(dataset))
    assert builtin is None or isinstance(caught.value, builtin)
    assert not str(caught.value).startswith(("'", '"'))     # the message as written, not a repr


@pytest.mark.parametrize("call, builtin, words", [
    (lambda r: r.sample(10), IndexError, "sample 10 out of range"),
    (lambda r: r.row(-11), IndexError, "out of range"),
    (lambda r: r.window("ep_b", 3, -1), None, "k must be >= 0"),
    (lambda r: r.window("ep_b", 1, 2), IndexError, "cross the start"),
    (lambda r: list(r.iter_samples(shards=[99])), IndexError, "no shard 99"),
])
def test_a_readers_callers_mistake_is_an_argument_error(dataset, call, builtin, words):
    with pytest.raises(ArgumentError, match=words) as caught:
        call(DatasetReader(dataset))
    assert builtin is None or isinstance(caught.value, builtin)


def test_an_unknown_version_is_an_argument_error(dataset):
    with pytest.raises(ArgumentError, match="no version 9") as caught:
        DatasetMetadata(dataset, version=9)
    assert isinstance(caught.value, FileNotFoundError)    # what callers caught before


def test_records_that_disagree_are_a_dataset_error(copy):
    manifest = json.loads((copy / MANIFEST_FILE).read_text())
    manifest["counts"]["episodes"] = 4
    rewrite_manifest(copy, manifest)
    with pytest.raises(DatasetError, match="(episodes.jsonl has|its segments hold) 3 records, manifest counts 4"):
        DatasetMetadata(copy)
    manifest["counts"] = {**manifest["counts"], "episodes": 3, "samples": 11}
    rewrite_manifest(copy, manifest)
    meta = DatasetMetadata(copy)
    with pytest.raises(DatasetError, match="index has 10 rows, manifest counts 11"):
        meta.index


def test_a_split_naming_an_unknown_episode_is_a_dataset_error(copy):
    manifest = json.loads((copy / MANIFEST_FILE).read_text())
    entry = manifest["splits"]["main"]
    doc = json.loads((copy / entry["file"]).read_text())
    doc["parts"]["val"]["episodes"].append("ep_gone")
    data = (json.dumps(doc) + "\n").encode()
    (copy / entry["file"]).write_bytes(data)
    entry["sha256"] = hashlib.sha256(data).hexdigest()
    rewrite_manifest(copy, manifest)
    with pytest.raises(DatasetError, match="unknown episode.*ep_gone"):
        DatasetMetadata(copy).sample_indices("main", "val")
