import os
import pickle

import numpy as np
import pytest

from htdata.format.table import MANIFEST_FILE, SEGMENTS_DIR
from htdata.read.reader import DatasetReader
from htdata.store.versions import VERSIONS_DIR
from tests.factories import (
    MIXED_HANDS_EPISODES,
    commit_split,
    default_canonical,
    mixed_hands_coverages,
    synthetic_members,
    synthetic_tactile,
    write_synthetic_dataset,
)
from tests.factories.legacy import reseal_index

EPISODES = MIXED_HANDS_EPISODES
SEED = 7



@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "ds"
    return write_synthetic_dataset(root, EPISODES, seed=SEED, coverages=mixed_hands_coverages(),
                                   samples_per_shard=3, bend_dims=4)


def expected(spec_id, frame):
    spec = next(e for e in EPISODES if e["episode_id"] == spec_id)
    return synthetic_members(spec, frame, SEED, mixed_hands_coverages(), bend_dims=4)


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
        truth = synthetic_tactile(SEED, "ep_b", 2, hand, mixed_hands_coverages()[f"glove_{hand[0]}"])
        assert np.abs(d["tactile"][hand] - truth).max() <= 2.5e-4
        assert d["bend"][hand].shape == (4,) and d["bend"][hand].dtype == np.float32
    assert d["tactile"]["left"][mixed_hands_coverages()["glove_l"] == 0].max() == 0.0
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
    assert np.array_equal(r.coverage("glove_r"), mixed_hands_coverages()["glove_r"])
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
    commit_split(dataset, "main", {"train": ["ep_c", "ep_a"], "val": ["ep_b"]})
    with pytest.raises(FileNotFoundError, match="main"):
        r.split("main")                  # r reads the version it opened: the split is in the next one
    r = DatasetReader(dataset)
    assert set(r.split("main")["parts"]) == {"train", "val"}
    assert list(r.sample_indices("main", "train")) == [0, 1, 2, 3, 4, 9]
    assert list(r.sample_indices("main", "val")) == [5, 6, 7, 8]
    with pytest.raises(KeyError, match="test"):
        r.sample_indices("main", "test")


def test_corrupt_index_offset_is_detected(dataset, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    reseal_index(copy, lambda rows: rows["offset"].__setitem__(1, rows["offset"][2]))
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

    from htdata.store import storage

    assert storage.exists(storage.join(dataset, MANIFEST_FILE))
    assert VERSIONS_DIR in storage.listdir(dataset)
    assert SEGMENTS_DIR in storage.listdir(dataset)
    fs = fsspec.filesystem("memory")
    fs.pipe("/st/a/x.bin", b"abc")
    assert storage.is_url("memory://st") and not storage.is_url(f"file://{dataset}")
    assert storage.join("memory://st/", "a", "x.bin") == "memory://st/a/x.bin"
    assert storage.read_bytes("memory://st/a/x.bin") == b"abc"
    assert storage.listdir("memory://st/a") == ["x.bin"]
    assert not storage.exists("memory://st/a/y.bin")
    fs.rm("/st", recursive=True)


# -- hot-path helpers (cheap header check, fast .npy, partial reads) -----------------------

def _copy(dataset, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    return copy


def test_row_matches_index_fields(dataset):
    from htdata.format.table import SIZE_FIELDS

    r = DatasetReader(dataset)
    for i in (0, 5, 9, -1):
        row, raw = r.row(i), r.index[i % len(r)]
        assert (row.shard, row.offset, row.episode, row.frame) == (
            int(raw["shard"]), int(raw["offset"]), int(raw["episode"]), int(raw["frame"]))
        assert row.sizes == tuple(int(raw[f]) for f in SIZE_FIELDS.values())
        assert all(type(v) is int for v in (row.shard, row.offset, *row.sizes))
    with pytest.raises(IndexError, match="out of range"):
        r.row(-11)


def test_member_layout_offsets_and_early_stop():
    from htdata.read.reader import member_layout

    sizes = (10, 600, 0, 512, 3, 0)   # json, rgb, (no left), right, bend_left, (no bend_right)
    layout, end = member_layout(sizes)
    assert layout == [("json", 0, 10), ("rgb.jpg", 1024, 600), ("tactile_right.exr", 2560, 512),
                      ("bend_left.npy", 3584, 3)]
    assert end == 3584 + 512 + 3
    layout, end = member_layout(sizes, ("rgb.jpg", "tactile_left.exr"))
    assert layout == [("rgb.jpg", 1024, 600)] and end == 1024 + 512 + 600
    assert member_layout((0,) * 6) == ([], 0)


def test_header_check_fast_path_fallback_and_mismatch():
    import tarfile

    from htdata.format.shardio import header_matches, member_header

    name = "ep_a__000001.json"
    ours = member_header(name, 1234)
    assert header_matches(ours, name.encode(), 1234)
    assert not header_matches(ours, name.encode(), 1235)
    assert not header_matches(ours, b"ep_a__000001.jso", 1234)       # prefix of the stored name
    assert not header_matches(ours, (name + "n").encode(), 1234)     # stored name is a prefix
    # another valid encoding of the same size (space-terminated, as some tar writers do):
    # the byte comparison fails, tarfile's parser decides
    other = bytearray(ours)
    other[124:136] = b"%011o " % 1234
    other[148:156] = b"        "
    other[148:156] = b"%06o\0 " % tarfile.calc_chksums(bytes(other))[0]
    assert other[124:136] != ours[124:136] and tarfile.TarInfo.frombuf(bytes(other), "utf-8", "strict").size == 1234
    assert header_matches(bytes(other), name.encode(), 1234)
    assert not header_matches(bytes(other), name.encode(), 1233)
    assert not header_matches(b"\xff" * 512, name.encode(), 1234)    # garbage: no exception
    # a 100-byte name fills the field with no NUL terminator
    long_name = "e" * 95 + ".json"
    assert header_matches(member_header(long_name, 7), long_name.encode(), 7)


@pytest.mark.parametrize("arr", [
    np.arange(4, dtype=np.float32), np.float16([1.5, -2.0]), np.zeros((0,), np.float32),
    np.array(3.25), np.arange(6, dtype=np.int16).reshape(2, 3),
    np.asfortranarray(np.arange(6, dtype=np.float64).reshape(2, 3)),
])
def test_decode_npy_matches_np_load_on_miss_and_hit(arr):
    import io

    from htdata.format.codec import decode_npy

    buf = io.BytesIO()
    np.save(buf, arr)
    data = buf.getvalue()
    for _ in range(2):   # first call parses the header, second uses the cached parse
        out = decode_npy(data, "x")
        assert out.dtype == arr.dtype and out.shape == arr.shape and np.array_equal(out, arr)
        assert out.flags.writeable
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, version=(2, 0))
    assert np.array_equal(decode_npy(buf.getvalue(), "x"), arr)


def test_decode_npy_errors_name_the_member():
    import io

    from htdata.format.codec import decode_npy

    buf = io.BytesIO()
    np.save(buf, np.arange(5, dtype=np.float32))
    data = buf.getvalue()
    decode_npy(data, "warm")   # header now cached: the cached path must also check the length
    with pytest.raises(ValueError, match="k__000001.bend_left.npy.*data bytes"):
        decode_npy(data[:-4], "k__000001.bend_left.npy")
    with pytest.raises(ValueError, match="k__000002.bend_left.npy.*data bytes"):
        decode_npy(data + b"\0" * 4, "k__000002.bend_left.npy")
    with pytest.raises(ValueError, match="k__3: not an .npy"):
        decode_npy(b"{json}", "k__3")
    other = io.BytesIO()
    np.save(other, np.arange(7, dtype=np.int64))
    with pytest.raises(ValueError, match="k__4: unreadable"):
        decode_npy(other.getvalue()[:-8], "k__4")   # unseen header: np.load reports it


def test_bend_decoding_matches_np_load(dataset):
    import io

    r = DatasetReader(dataset)
    for i in range(len(r)):
        members = r.sample(i)
        d = r.decode(members)
        for hand in ("left", "right"):
            if f"bend_{hand}.npy" in members:
                want = np.load(io.BytesIO(members[f"bend_{hand}.npy"])).astype(np.float32)
                assert np.array_equal(d["bend"][hand], want)


def test_partial_reads_are_byte_exact_subsets(dataset):
    r = DatasetReader(dataset)
    wanted = ("rgb.jpg", "tactile_left.exr")
    for i in range(len(r)):
        full = r.sample(i)
        part = r.sample(i, suffixes=wanted)
        assert part == {k: v for k, v in full.items() if k in wanted}
        row, key, members = r.read_sample(i, ("json",))
        assert key == r.key(i) and members == {"json": full["json"]} and row == r.row(i)
    streamed = dict(r.iter_samples(suffixes=("json",)))
    assert streamed == {i: {"json": r.sample(i)["json"]} for i in range(len(r))}
    d = r.decoded(0, suffixes=("rgb.jpg",))
    assert "meta" not in d and d["rgb"].shape == (224, 224, 3) and d["tactile"] == {}


def test_truncated_shard_names_the_sample_but_early_members_still_read(dataset, tmp_path):
    copy = _copy(dataset, tmp_path)
    r = DatasetReader(copy)
    last = len(r) - 1
    row, key = r.row(last), r.key(last)
    shard = copy / "shards" / r.manifest["shards"][row.shard]["name"]
    data = shard.read_bytes()
    cut = row.offset + 512 + row.sizes[0] + 100   # mid-way through the rgb member
    shard.write_bytes(data[:cut])
    r = DatasetReader(copy)
    assert r.sample(last, suffixes=("json",)) == DatasetReader(dataset).sample(last, suffixes=("json",))
    with pytest.raises(ValueError, match=f"truncated at sample {key}"):
        r.sample(last)


def test_corrupt_size_field_and_undecodable_member_name_the_sample(dataset, tmp_path):
    copy = _copy(dataset, tmp_path)
    r = DatasetReader(copy)
    i = r.locate("ep_b", 1)
    row, key = r.row(i), r.key(i)
    shard = copy / "shards" / r.manifest["shards"][row.shard]["name"]
    data = bytearray(shard.read_bytes())
    json_header = row.offset
    data[json_header + 124:json_header + 136] = b"%011o\0" % (row.sizes[0] + 1)   # size field lies
    rgb_data = row.offset + 512 + (row.sizes[0] + 511) // 512 * 512 + 512
    data[rgb_data:rgb_data + row.sizes[1]] = bytes(row.sizes[1])                 # JPEG zeroed
    shard.write_bytes(bytes(data))
    r = DatasetReader(copy)
    with pytest.raises(ValueError, match=f"expected member {key}.json .*index and shard disagree"):
        r.sample(i)
    with pytest.raises(ValueError, match=f"{key}.rgb.jpg: not a decodable JPEG"):
        r.decoded(i, suffixes=("rgb.jpg",))


def test_front_door_opens_a_version_and_its_torch_datasets(tmp_path):
    import htdata

    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    ds = htdata.open(root)
    assert isinstance(ds, DatasetReader) and ds.version == 1 and len(ds) == len(DatasetReader(root))
    assert htdata.open(root, version=1).manifest == ds.manifest
    frames = ds.torch.frames()
    assert len(frames) > 0 and frames._builder.reader.version == ds.version
    assert ds.torch.windows(window=2)[0]["tactile"].shape[0] == 2


def test_old_module_names_still_import_and_warn():
    import importlib
    import sys
    import warnings

    import htdata.read.reader as new
    sys.modules.pop("htdata.reader", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = importlib.import_module("htdata.reader")
    assert old is new and new.__spec__.name == "htdata.read.reader"
    assert any(issubclass(w.category, DeprecationWarning) and "htdata.read.reader" in str(w.message) for w in caught)
    from htdata.format import SHARDS_DIR
    assert SHARDS_DIR == "shards"
