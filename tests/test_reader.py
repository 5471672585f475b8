import json
import os
import pickle

import numpy as np
import pytest

from htdata.reader import DatasetReader
from tests.factories import (default_canonical, synthetic_members, synthetic_tactile,
                             write_synthetic_dataset)

EPISODES = [
    {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": ("right",), "num_frames": 5,
     "layouts": {"right": "glove_r"}},
    {"episode_id": "ep_b", "task": "wipe", "scene": "office", "hands": ("left", "right"), "num_frames": 4,
     "layouts": {"left": "glove_l", "right": "glove_r"}},
    {"episode_id": "ep_c", "task": "pour", "scene": "office", "hands": ("left",), "num_frames": 1,
     "layouts": {"left": "glove_l"}},
]
SEED = 7


def coverages():
    right = np.zeros((224, 224), np.uint8)
    right[20:200, 30:190] = 1
    left = np.zeros((224, 224), np.uint8)
    left[40:220, 10:150] = 1
    return {"glove_r": right, "glove_l": left}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "ds"
    return write_synthetic_dataset(root, EPISODES, seed=SEED, coverages=coverages(),
                                   samples_per_shard=3, bend_dims=4)


def expected(spec_id, frame):
    spec = next(e for e in EPISODES if e["episode_id"] == spec_id)
    return synthetic_members(spec, frame, SEED, coverages(), bend_dims=4)


def test_random_access_is_byte_exact(dataset):
    r = DatasetReader(dataset)
    assert len(r) == 10
    for i in range(len(r)):
        key = r.key(i)
        eid, frame = key.rsplit("__", 1)
        assert r.sample(i) == expected(eid, int(frame))
    assert r.key(-1) == "ep_c__000000"
    with pytest.raises(IndexError, match="out of range"):
        r.sample(10)


def test_decoded_values(dataset):
    r = DatasetReader(dataset)
    i = r.locate("ep_b", 2)
    assert i == 7 and r.episode_range("ep_b") == (5, 4)
    d = r.decoded(i)
    assert d["rgb"].shape == (224, 224, 3) and d["rgb"].dtype == np.uint8
    assert d["meta"]["key"] == "ep_b__000002" and d["meta"]["hands"] == {"left": True, "right": True}
    for hand in ("left", "right"):
        truth = synthetic_tactile(SEED, "ep_b", 2, hand, coverages()[f"glove_{hand[0]}"])
        assert np.abs(d["tactile"][hand] - truth).max() <= 2.5e-4
        assert d["bend"][hand].shape == (4,) and d["bend"][hand].dtype == np.float32
    assert d["tactile"]["left"][coverages()["glove_l"] == 0].max() == 0.0
    single = r.decoded(r.locate("ep_a", 0))
    assert set(single["tactile"]) == {"right"}


def test_locate_errors_name_episode(dataset):
    r = DatasetReader(dataset)
    with pytest.raises(IndexError, match="ep_a.*0..4"):
        r.locate("ep_a", 5)
    with pytest.raises(KeyError, match="nope"):
        r.locate("nope", 0)


def test_window_frames_and_episode_start(dataset):
    r = DatasetReader(dataset)
    w = r.window("ep_b", 3, 2)
    assert [x["meta"]["frame_index"] for x in w] == [1, 2, 3]
    assert all(x["meta"]["episode_id"] == "ep_b" for x in w)
    assert [x["meta"]["frame_index"] for x in r.window(1, 0, 0)] == [0]
    with pytest.raises(IndexError, match="cross the start of episode 'ep_b'"):
        r.window("ep_b", 1, 2)
    with pytest.raises(IndexError, match="cross the start of episode 'ep_c'"):
        r.window("ep_c", 0, 1)


def test_streaming_matches_random_access(dataset):
    r = DatasetReader(dataset)
    streamed = list(r.iter_samples())
    assert [i for i, _ in streamed] == list(range(len(r)))
    for i, members in streamed:
        assert members == r.sample(i)
    sub = [i for i, _ in r.iter_samples(shards=[1])]
    shard = r.manifest["shards"][1]
    assert sub == list(range(shard["first_sample"], shard["first_sample"] + shard["samples"]))


def test_coverage_and_region_maps(dataset):
    r = DatasetReader(dataset)
    assert np.array_equal(r.coverage("glove_r"), coverages()["glove_r"])
    assert np.array_equal(r.region_map, default_canonical().part_map)
    assert set(np.unique(r.region_map)) == {0, 1, 2, 3, 4, 5, 6}
    assert np.array_equal(r.place_map, default_canonical().region_map)
    assert r.layout("glove_l")["layout_id"] == "glove_l"
    with pytest.raises(KeyError, match="glove_x"):
        r.coverage("glove_x")


def test_split_selection(dataset, tmp_path):
    r = DatasetReader(dataset)
    with pytest.raises(FileNotFoundError, match="main"):
        r.split("main")
    splits = dataset / "splits"
    splits.mkdir(exist_ok=True)
    (splits / "main.json").write_text(json.dumps(
        {"parts": {"train": {"episodes": ["ep_c", "ep_a"]}, "val": {"episodes": ["ep_b"]}}}))
    assert set(r.split("main")["parts"]) == {"train", "val"}
    assert list(r.sample_indices("main", "train")) == [0, 1, 2, 3, 4, 9]
    assert list(r.sample_indices("main", "val")) == [5, 6, 7, 8]
    with pytest.raises(KeyError, match="test"):
        r.sample_indices("main", "test")
    (splits / "main.json").unlink()


def test_corrupt_index_offset_is_detected(dataset, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    rows = np.load(copy / "index.npy")
    rows["offset"][1] = rows["offset"][2]
    np.save(copy / "index.npy", rows)
    r = DatasetReader(copy)
    with pytest.raises(ValueError, match="index and shard disagree"):
        r.sample(1)


def test_pickle_and_fork_reopen_handles(dataset):
    r = DatasetReader(dataset)
    first = r.sample(3)
    r2 = pickle.loads(pickle.dumps(r))
    assert r2._handles == {} and r2.sample(3) == first
    rfd, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: must open its own handles, not reuse the parent's
        try:
            ok = r.sample(3) == first and r._pid == os.getpid()
            os.write(wfd, b"1" if ok else b"0")
        finally:
            os._exit(0)
    os.waitpid(pid, 0)
    assert os.read(rfd, 1) == b"1"
    assert r.sample(3) == first  # parent handle still usable


def test_memory_url_round_trip(dataset):
    import fsspec

    fs = fsspec.filesystem("memory")
    for path in dataset.rglob("*"):
        if path.is_file():
            fs.pipe(f"/dsmem/{path.relative_to(dataset).as_posix()}", path.read_bytes())
    local = DatasetReader(dataset)
    remote = DatasetReader("memory://dsmem")
    assert len(remote) == len(local)
    for i in (0, 6, 9):
        assert remote.sample(i) == local.sample(i)
    assert [i for i, _ in remote.iter_samples()] == list(range(len(local)))
    assert np.array_equal(remote.coverage("glove_l"), local.coverage("glove_l"))
    fs.rm("/dsmem", recursive=True)


def test_file_url(dataset):
    r = DatasetReader(f"file://{dataset}")
    assert r.sample(2) == DatasetReader(dataset).sample(2)


def test_storage_helpers_local_and_memory(dataset):
    import fsspec

    from htdata import storage

    assert storage.exists(storage.join(dataset, "dataset.json"))
    assert "index.npy" in storage.listdir(dataset)
    fs = fsspec.filesystem("memory")
    fs.pipe("/st/a/x.bin", b"abc")
    assert storage.is_url("memory://st") and not storage.is_url(f"file://{dataset}")
    assert storage.join("memory://st/", "a", "x.bin") == "memory://st/a/x.bin"
    assert storage.read_bytes("memory://st/a/x.bin") == b"abc"
    assert storage.listdir("memory://st/a") == ["x.bin"]
    assert not storage.exists("memory://st/a/y.bin")
    fs.rm("/st", recursive=True)
