
import warnings

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from htdata.read.itemoptions import ItemOptions
from htdata.read.torchdata import (
    TactileFrameDataset,
    TactileStream,
    TactileWindowDataset,
    shards_for_consumer,
    shuffled_indices,
)
from tests.factories import (
    MIXED_HANDS_EPISODES,
    commit_split,
    default_canonical,
    synthetic_rgb,
    synthetic_tactile,
    write_synthetic_dataset,
)

EPISODES = MIXED_HANDS_EPISODES
SEED = 3


def coverages():
    right = np.zeros((224, 224), np.uint8)
    right[20:200, 30:190] = 1
    left = np.ones((224, 224), np.uint8)
    left[:10] = 0
    return {"glove_r": right, "glove_l": left}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("tds") / "ds"
    write_synthetic_dataset(root, EPISODES, seed=SEED, coverages=coverages(), samples_per_shard=2)
    commit_split(root, "main", {"train": ["ep_a", "ep_c"], "val": ["ep_b"]})
    return root


def test_frame_dataset_items_and_tensors(dataset):
    ds = TactileFrameDataset(dataset)
    assert len(ds) == 5 + 8 + 1
    item = ds[5]  # ep_b frame 0, left hand (left before right)
    assert item["tactile"].shape == (1, 224, 224) and item["tactile"].dtype == torch.float32
    assert item["coverage"].shape == (1, 224, 224) and item["coverage"].dtype == torch.float32
    assert item["regions"].shape == (224, 224) and item["regions"].dtype == torch.uint8
    assert item["rgb"].shape == (3, 224, 224) and item["rgb"].dtype == torch.uint8
    assert (int(item["hand"]), int(item["episode"]), int(item["frame"])) == (0, 1, 0)
    assert int(item["task"]) == 1 and int(item["scene"]) == 1  # wipe, office in sorted lists
    assert torch.equal(item["coverage"][0], torch.from_numpy(coverages()["glove_l"].astype(np.float32)))
    assert torch.equal(item["regions"], torch.from_numpy(default_canonical().part_map))
    truth = synthetic_tactile(SEED, "ep_b", 0, "left", coverages()["glove_l"])
    assert np.abs(item["tactile"][0].numpy() - truth).max() <= 2.5e-4
    # JPEG is lossy: close to the source frame, in RGB order
    rgb = item["rgb"].permute(1, 2, 0).numpy().astype(int)
    assert np.abs(rgb - synthetic_rgb(SEED, "ep_b", 0).astype(int)).mean() < 4
    assert int(ds[6]["hand"]) == 1


def test_frame_dataset_hands_split_and_rgb_float(dataset):
    assert len(TactileFrameDataset(dataset, options=ItemOptions(hands=("left",)))) == 4 + 1
    train = TactileFrameDataset(dataset, options=ItemOptions(split="main", part="train"))
    assert len(train) == 6 and {int(train[i]["episode"]) for i in range(len(train))} == {0, 2}
    val = TactileFrameDataset(dataset, options=ItemOptions(split="main", part="val", rgb_float=True))
    rgb = val[0]["rgb"]
    assert rgb.dtype == torch.float32 and 0.0 <= float(rgb.min()) and float(rgb.max()) <= 1.0
    with pytest.raises(ValueError, match="hands"):
        TactileFrameDataset(dataset, options=ItemOptions(hands=("middle",)))
    with pytest.raises(ValueError, match="choose a part"):
        TactileFrameDataset(dataset, options=ItemOptions(split="main"))


def test_window_dataset_never_crosses_episodes(dataset):
    ds = TactileWindowDataset(dataset, window=3)
    # ep_a: T=2..4 (right); ep_b: T=2,3 x (left, right); ep_c has 1 frame: no full window
    assert len(ds) == 3 + 4
    for i in range(len(ds)):
        item = ds[i]
        assert item["tactile"].shape == (3, 1, 224, 224) and item["rgb"].shape == (3, 3, 224, 224)
        frames = item["frame"].tolist()
        assert frames == list(range(frames[-1] - 2, frames[-1] + 1)) and frames[0] >= 0
    item = ds[3]  # ep_b T=2, left
    assert (int(item["episode"]), int(item["hand"]), item["frame"].tolist()) == (1, 0, [0, 1, 2])
    for k, f in enumerate(item["frame"].tolist()):
        truth = synthetic_tactile(SEED, "ep_b", f, "left", coverages()["glove_l"])
        assert np.abs(item["tactile"][k, 0].numpy() - truth).max() <= 2.5e-4
    assert len(TactileWindowDataset(dataset, window=1)) == len(TactileFrameDataset(dataset))
    assert len(TactileWindowDataset(dataset, window=6)) == 0
    with pytest.raises(ValueError, match="window"):
        TactileWindowDataset(dataset, window=0)


def _collect(loader):
    out = []
    for batch in loader:
        for j in range(len(batch["index"])):
            out.append((int(batch["index"][j]), int(batch["hand"][j]),
                        float(batch["tactile"][j].sum()), int(batch["rgb"][j].sum())))
    return out


def test_dataloader_two_workers_matches_zero(dataset):
    ds = TactileFrameDataset(dataset)
    serial = _collect(DataLoader(ds, batch_size=4, num_workers=0))
    parallel = _collect(DataLoader(ds, batch_size=4, num_workers=2))
    assert serial == parallel and len(serial) == len(ds)


def test_stream_covers_every_item_once_with_workers(dataset):
    stream = TactileStream(dataset)
    serial = _collect(DataLoader(stream, batch_size=3, num_workers=0))
    parallel = _collect(DataLoader(stream, batch_size=3, num_workers=2))
    frames = _collect(DataLoader(TactileFrameDataset(dataset), batch_size=5))
    assert serial == frames  # in order with one consumer
    assert sorted(parallel) == sorted(frames) and len(stream) == len(frames)
    val = TactileStream(dataset, options=ItemOptions(split="main", part="val", hands=("right",)))
    assert [int(x["index"]) for x in val] == [5, 6, 7, 8]


def test_shard_assignment_is_a_deterministic_partition():
    for seed in (None, 11):
        parts = [shards_for_consumer(10, c, 4, seed, epoch=2) for c in range(4)]
        assert sorted(sum(parts, [])) == list(range(10))
        assert parts == [shards_for_consumer(10, c, 4, seed, epoch=2) for c in range(4)]
    assert shards_for_consumer(2, 3, 4, None, 0) == []
    assert shards_for_consumer(10, 0, 1, 11, 0) != shards_for_consumer(10, 0, 1, 11, 1)


def test_shuffled_indices():
    a = shuffled_indices(100, seed=5, epoch=0)
    assert sorted(a.tolist()) == list(range(100))
    assert np.array_equal(a, shuffled_indices(100, 5, 0))
    assert not np.array_equal(a, shuffled_indices(100, 5, 1))
    assert len(shuffled_indices(0, 5, 0)) == 0
    with pytest.raises(ValueError):
        shuffled_indices(-1, 0, 0)


def test_stream_splits_shards_across_ddp_ranks(dataset, monkeypatch):
    import htdata.read.torchdata as td

    stream = TactileStream(dataset)
    n_shards = len(stream.reader.manifest["shards"])
    seen = []
    for rank in (0, 1):
        monkeypatch.setattr(td, "_dist_rank_world", lambda rank=rank: (rank, 2))
        seen.append(stream.my_shards())
    assert seen == [list(range(0, n_shards, 2)), list(range(1, n_shards, 2))]
    items = []
    for rank in (0, 1):
        monkeypatch.setattr(td, "_dist_rank_world", lambda rank=rank: (rank, 2))
        items += [(int(x["index"]), int(x["hand"])) for x in stream]
    assert sorted(items) == sorted((int(x["index"]), int(x["hand"])) for x in TactileFrameDataset(dataset))


# -- fast item path: same tensors as decoding the sample through the reader -----------------

def _reference_item(reader, index, hand):
    """What an item must hold, built the slow obvious way from DatasetReader.decoded."""
    d = reader.decoded(index)
    return d["tactile"][hand][None], np.ascontiguousarray(d["rgb"].transpose(2, 0, 1))


def test_frame_items_equal_reader_decode(dataset):
    ds = TactileFrameDataset(dataset)
    floats = TactileFrameDataset(dataset, options=ItemOptions(rgb_float=True))
    for i in range(len(ds)):
        item, fitem = ds[i], floats[i]
        hand = ("left", "right")[int(item["hand"])]
        tactile, rgb = _reference_item(ds.reader, int(item["index"]), hand)
        assert np.array_equal(item["tactile"].numpy(), tactile)
        assert np.array_equal(item["rgb"].numpy(), rgb) and item["rgb"].is_contiguous()
        assert np.array_equal(fitem["rgb"].numpy(), rgb.astype(np.float32) / np.float32(255.0))
        assert item["episode"].dtype == torch.long and item["episode"].shape == ()


def test_window_items_equal_stacked_frames(dataset):
    ds = TactileWindowDataset(dataset, window=2, options=ItemOptions(rgb_float=True))
    frames = TactileFrameDataset(dataset, options=ItemOptions(rgb_float=True))
    by_key = {(int(f["index"]), int(f["hand"])): f for f in frames}
    assert len(ds) == 4 + 2 * 3
    for i in range(len(ds)):
        item = ds[i]
        hand = int(item["hand"])
        parts = [by_key[(int(j), hand)] for j in item["index"]]
        assert torch.equal(item["tactile"], torch.stack([p["tactile"] for p in parts]))
        assert torch.equal(item["rgb"], torch.stack([p["rgb"] for p in parts]))
        assert item["frame"].tolist() == [int(p["frame"]) for p in parts]
        assert item["index"].dtype == torch.long and item["frame"].dtype == torch.long
        assert torch.equal(item["coverage"], parts[-1]["coverage"])


def test_stream_items_equal_frame_items_and_do_not_alias(dataset):
    frames = {(int(f["index"]), int(f["hand"])): f for f in TactileFrameDataset(dataset)}
    stream = list(TactileStream(dataset))
    assert [(int(s["index"]), int(s["hand"])) for s in stream] == list(frames)
    for s in stream:
        f = frames[(int(s["index"]), int(s["hand"]))]
        for name in ("tactile", "rgb", "coverage", "regions", "task", "scene", "episode", "frame"):
            assert torch.equal(s[name], f[name]), name
    # ep_b frame 0 has both hands: the JPEG is decoded once but each item owns its rgb
    left, right = (s for s in stream if int(s["index"]) == 5)
    before = right["rgb"].clone()
    left["rgb"].zero_()
    left["tactile"].fill_(7.0)
    assert torch.equal(right["rgb"], before) and float(right["tactile"].max()) <= 1.0


def test_put_rgb_matches_transpose():
    from htdata.read.torchitems import ItemBuilder

    rgb = np.random.default_rng(0).integers(0, 256, (224, 224, 3), dtype=np.uint8)
    builder = ItemBuilder.__new__(ItemBuilder)
    out = np.empty((3, 224, 224), np.uint8)
    builder.put_rgb(out, rgb)
    assert np.array_equal(out, rgb.transpose(2, 0, 1))
    fout = np.empty((3, 224, 224), np.float32)
    builder.put_rgb(fout, rgb)
    assert np.array_equal(fout, rgb.transpose(2, 0, 1).astype(np.float32) / np.float32(255.0))
    assert fout.max() <= 1.0 and fout.min() >= 0.0


def test_corrupt_tactile_member_error_names_the_sample(dataset, tmp_path):
    import shutil

    from htdata.read.reader import DatasetReader, member_layout

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    reader = DatasetReader(copy)
    index = reader.locate("ep_a", 2)
    row, key = reader.row(index), reader.key(index)
    (_, rel, size), = member_layout(row.sizes, ("tactile_right.exr",))[0]
    shard = copy / "shards" / reader.manifest["shards"][row.shard]["name"]
    data = bytearray(shard.read_bytes())
    data[row.offset + rel + 512:row.offset + rel + 512 + size] = bytes(size)
    shard.write_bytes(bytes(data))
    ds = TactileFrameDataset(copy, options=ItemOptions(hands=("right",)))
    with pytest.raises(ValueError, match=f"{key}.tactile_right.exr: undecodable EXR"):
        ds[2]
    windows = TactileWindowDataset(copy, window=3, options=ItemOptions(hands=("right",)))
    with pytest.raises(ValueError, match=f"{key}.tactile_right.exr"):
        windows[0]
    assert int(ds[1]["frame"]) == 1   # other samples still read
    with pytest.raises(ValueError, match=f"{key}.tactile_right.exr: undecodable EXR"):
        DatasetReader(copy).decoded(index)


def test_loader_bench_rows_decode_what_each_access_decodes(dataset):
    from htdata.benchmarks.loader import loader_rows

    out = loader_rows(dataset, n_random=6, n_windows=3, seed=1, passes=1)
    rows = {r["access"]: r for r in out["rows"]}
    assert len(rows) == 7 and out["samples_in_dataset"] == 10 and out["bound"]["samples"] == 6
    assert rows["reader random decoded(i)"]["samples_decoded"] == 6
    assert rows["reader window k=2 (3 frames)"]["samples_decoded"] == 3 * rows["reader window k=2 (3 frames)"]["items"]
    assert rows["reader stream iter_samples"]["samples_decoded"] == 10
    assert rows["TactileWindowDataset item (3 frames)"]["samples_decoded"] == 9
    stream = rows["TactileStream (one worker)"]
    assert stream["items"] == len(TactileFrameDataset(dataset)) and stream["samples_decoded"] == 10
    for r in rows.values():
        assert r["seconds"] > 0 and r["bound_seconds"] > 0
        assert r["ratio_to_bound"] == pytest.approx(r["bound_seconds"] / r["seconds"])
        assert r["samples_per_s"] == pytest.approx(r["samples_decoded"] / r["seconds"])


def test_datasets_read_an_older_version(tmp_path):
    from htdata.curate.edit import remove_episodes

    root = write_synthetic_dataset(tmp_path / "ds", MIXED_HANDS_EPISODES, seed=SEED, coverages=coverages())
    remove_episodes(root, ["ep_b"], dry_run=False, command="rm")
    assert len(TactileFrameDataset(root)) == 5 + 1
    old = TactileFrameDataset(root, options=ItemOptions(version=1))
    assert len(old) == 5 + 8 + 1 and old.reader.version == 1
    assert len(TactileWindowDataset(root, window=2, options=ItemOptions(version=1))) > \
        len(TactileWindowDataset(root, window=2))
    assert len(list(TactileStream(root, options=ItemOptions(version=1)))) == len(old)


# ---- what an item carries (htdata/read/torchitems.py) ------------------------------------
def test_tactile_only_items_equal_the_tactile_of_full_items(dataset):
    full = TactileFrameDataset(dataset)
    tactile = TactileFrameDataset(dataset, options=ItemOptions(members=("tactile",)))
    rgb_only = TactileFrameDataset(dataset, options=ItemOptions(members=("rgb",)))
    assert len(tactile) == len(full) == len(rgb_only)
    for i in range(len(full)):
        a, t, r = full[i], tactile[i], rgb_only[i]
        assert "rgb" not in t and "tactile" not in r
        assert torch.equal(t["tactile"], a["tactile"]) and torch.equal(r["rgb"], a["rgb"])
        assert int(t["index"]) == int(a["index"]) and int(t["hand"]) == int(a["hand"])
    # windows and streams honour the same choice
    win_full = TactileWindowDataset(dataset, window=2)
    win_t = TactileWindowDataset(dataset, window=2, options=ItemOptions(members=("tactile",)))
    assert "rgb" not in win_t[0] and torch.equal(win_t[0]["tactile"], win_full[0]["tactile"])
    stream_t = list(TactileStream(dataset, options=ItemOptions(members=("tactile",))))
    assert [torch.equal(s["tactile"], full[i]["tactile"]) for i, s in enumerate(stream_t)] == [True] * len(full)
    stream_r = list(TactileStream(dataset, options=ItemOptions(members=("rgb",))))
    assert [torch.equal(s["rgb"], full[i]["rgb"]) for i, s in enumerate(stream_r)] == [True] * len(full)
    with pytest.raises(ValueError, match="members"):
        TactileFrameDataset(dataset, options=ItemOptions(members=("depth",)))
    with pytest.raises(ValueError, match="constants"):
        TactileFrameDataset(dataset, options=ItemOptions(constants="never"))


def test_constants_sent_once_give_the_same_batches(dataset):
    from htdata.read.torchitems import expand_batch

    full = TactileFrameDataset(dataset)
    once = TactileFrameDataset(dataset, options=ItemOptions(constants="once"))
    item = once[0]
    assert set(item) == {"tactile", "rgb", "ids"} and item["ids"].shape == (8,) and item["ids"].dtype == torch.int64
    constants = once.constants()
    assert constants.coverage.dtype == torch.uint8 and constants.coverage.shape[1:] == (1, 224, 224)
    a_batches = list(DataLoader(full, batch_size=4, num_workers=0))
    b_batches = list(DataLoader(once, batch_size=4, num_workers=2))
    assert len(a_batches) == len(b_batches)
    for a, b in zip(a_batches, b_batches):
        b = expand_batch(b, constants)
        assert set(a) == set(b)
        for k in a:
            assert a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]), k
    once = ItemOptions(constants="once", members=("tactile",))
    stream = list(DataLoader(TactileStream(dataset, options=once), batch_size=5))
    frames = list(DataLoader(TactileFrameDataset(dataset, options=ItemOptions(members=("tactile",))), batch_size=5))
    for a, b in zip(frames, stream):
        b = expand_batch(b, constants)
        assert all(torch.equal(a[k], b[k]) for k in a)


def test_the_old_map_source_keyword_warns_and_still_chooses_the_maps(dataset):
    """`map_source=` (renamed `maps_from=`, htdata/_moved.py renamed_keyword) works until REMOVED_IN, warning."""
    best = TactileFrameDataset(dataset)
    for old, new in (("auto", "best"), ("stored", "stored"), ("raw", "raw")):
        with pytest.warns(DeprecationWarning, match=f"map_source='{old}'.*maps_from='{new}'"):
            ds = TactileFrameDataset(dataset, map_source=old)
        assert ds._builder.serving == TactileFrameDataset(dataset, options=ItemOptions(maps_from=new))._builder.serving
    with pytest.warns(DeprecationWarning, match="map_source"):
        stream = TactileStream(dataset, map_source="stored")
    with pytest.warns(DeprecationWarning, match="map_source"):
        windows = TactileWindowDataset(dataset, window=2, map_source="auto")
    assert torch.equal(next(iter(stream))["tactile"], best[0]["tactile"])
    assert np.array_equal(windows.items, TactileWindowDataset(dataset, window=2).items)
    assert TactileFrameDataset(dataset, options=ItemOptions(maps_from="raw"))._builder.serving.raw_required
    with pytest.raises(TypeError, match="map_source= and maps_from="):
        TactileFrameDataset(dataset, map_source="auto", maps_from="best")
    with pytest.raises(ValueError, match="maps_from must be one of .*the old map_source='auto' is 'best'"):
        TactileFrameDataset(dataset, options=ItemOptions(maps_from="auto"))


# ---- one options object for the three datasets (htdata/read/itemoptions.py) ----------------
def test_one_options_object_serves_the_three_datasets(dataset):
    from htdata.errors import ArgumentError

    opts = ItemOptions(split="main", part="val", hands=["right"], members=("tactile",), rgb_float=True)
    assert opts.hands == ("right",) and opts.replace(part="train").part == "train"
    frames = TactileFrameDataset(dataset, options=opts)
    assert frames.options is opts and len(frames) and "rgb" not in frames[0]
    assert {int(h) for _, h in frames.items} == {1}
    windows = TactileWindowDataset(dataset, window=2, options=opts)
    assert windows.options is opts and set(windows.items[:, 0]) <= set(frames.items[:, 0])
    stream = [(int(x["index"]), int(x["hand"])) for x in TactileStream(dataset, options=opts)]
    assert stream == [tuple(r) for r in frames.items.tolist()]
    with pytest.raises(ArgumentError, match="options must be an htdata.read.itemoptions.ItemOptions, got dict"):
        TactileFrameDataset(dataset, options={"split": "main"})
    with pytest.raises(ArgumentError, match="options.constants must be 'item'"):
        TactileWindowDataset(dataset, window=2, options=opts.replace(constants="once"))
    with pytest.raises(ArgumentError, match="hands must be"):
        opts.replace(hands=("middle",))
    with pytest.raises(ArgumentError, match="frames must be"):
        ItemOptions(frames="all")


def test_the_old_keywords_warn_and_make_the_same_options(dataset):
    """The nine keywords of before (htdata/_moved.py folded_keywords) work until REMOVED_IN, warning."""
    from htdata.errors import ArgumentError

    opts = ItemOptions(split="main", part="val", hands=("right",), members=("tactile",), rgb_float=True)
    keywords = dict(split="main", part="val", hands=("right",), members=("tactile",), rgb_float=True)
    with pytest.warns(DeprecationWarning, match=r"TactileFrameDataset\(split='main', .*\) is deprecated: "
                                                r"pass options=ItemOptions\(split='main'"):
        by_kw = TactileFrameDataset(dataset, **keywords)
    assert by_kw.options == opts and np.array_equal(by_kw.items, TactileFrameDataset(dataset, options=opts).items)
    with pytest.warns(DeprecationWarning, match="TactileWindowDataset"):
        assert TactileWindowDataset(dataset, window=2, **keywords).options == opts
    with pytest.warns(DeprecationWarning, match="TactileStream"):
        assert TactileStream(dataset, shuffle_seed=3, **keywords).options == opts
    # the old signatures took them by position too (the stream's fifth: shuffle_seed)
    with pytest.warns(DeprecationWarning):
        assert TactileFrameDataset(dataset, "main", "val").options == ItemOptions(split="main", part="val")
    with pytest.warns(DeprecationWarning):
        assert TactileWindowDataset(dataset, 2, "main", "val").options == ItemOptions(split="main", part="val")
    with pytest.warns(DeprecationWarning):
        stream = TactileStream(dataset, "main", "val", ("right",), False, 7)
    assert stream.shuffle_seed == 7 and stream.options == ItemOptions(split="main", part="val", hands=("right",))
    with pytest.raises(ArgumentError, match="not both .*also given: part"):
        TactileFrameDataset(dataset, part="train", options=opts)
    with pytest.raises(TypeError, match="got multiple values for argument 'split'"):
        TactileFrameDataset(dataset, "main", split="main")
    with warnings.catch_warnings():
        warnings.simplefilter("error")       # no old keyword: no warning
        assert TactileFrameDataset(dataset).options == ItemOptions()


def test_the_torch_view_puts_its_version_into_an_options_object(tmp_path):
    import htdata
    from htdata.curate.edit import remove_episodes
    from htdata.errors import ArgumentError

    root = write_synthetic_dataset(tmp_path / "ds", MIXED_HANDS_EPISODES, seed=SEED, coverages=coverages())
    remove_episodes(root, ["ep_b"], dry_run=False, command="rm")
    old = htdata.open(root, version=1).torch
    assert len(old.frames(options=ItemOptions(hands=("left",)))) == 4 + 1       # ep_b's left hand is in v1
    assert old.frames(options=ItemOptions()).reader.version == 1 and len(old.frames()) == 5 + 8 + 1
    with pytest.raises(TypeError, match="version"):
        old.frames(version=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")       # the view takes the fields as keywords: not the deprecated path
        left = old.windows(window=2, hands=("left",))
    assert left.options == ItemOptions(hands=("left",), version=1)
    with pytest.raises(ArgumentError, match="not both"):
        old.stream(options=ItemOptions(), part="train")
