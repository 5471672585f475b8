"""A streaming reader's `on_error=` (htdata/read/onerror.py): raise (default), warn and skip, or skip.

A sample whose JPEG does not decode and a shard file gone: "raise" gives the error as before, "warn" one
warning line naming the sample (or the shard) and the rest of the stream, "skip" the same without a word.
"""

import logging

import pytest

from htdata.errors import ArgumentError, DatasetError
from htdata.format.table import RGB_MEMBER, SHARDS_DIR
from htdata.read.itemoptions import ItemOptions
from htdata.read.reader import DatasetReader
from tests.factories import MIXED_HANDS_EPISODES, mixed_hands_coverages, write_synthetic_dataset
from tests.factories.hostile import rewrite_members

BAD = 3     # the sample whose JPEG is damaged


@pytest.fixture(scope="module")
def damaged(tmp_path_factory):
    root = tmp_path_factory.mktemp("onerror") / "ds"
    write_synthetic_dataset(root, MIXED_HANDS_EPISODES, coverages=mixed_hands_coverages(), samples_per_shard=2)
    rewrite_members(root, BAD, {RGB_MEMBER: b"not a jpeg at all"})
    return root


def streamed(root, on_error, caplog, **kw):
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="htdata.read"):
        got = [i for i, _ in DatasetReader(root).iter_samples(decode=True, on_error=on_error, **kw)]
    return got, [r.getMessage() for r in caplog.records]


def test_raise_is_the_default_and_names_the_sample(damaged):
    with pytest.raises(DatasetError, match="rgb.jpg"):
        list(DatasetReader(damaged).iter_samples(decode=True))


def test_warn_skips_the_sample_with_one_line_naming_it_and_skip_says_nothing(damaged, caplog):
    n = len(DatasetReader(damaged))
    got, lines = streamed(damaged, "warn", caplog)
    assert got == [i for i in range(n) if i != BAD]
    assert len(lines) == 1 and f"skipped sample {BAD} of shard" in lines[0] and "rgb.jpg" in lines[0]
    got, lines = streamed(damaged, "skip", caplog)
    assert got == [i for i in range(n) if i != BAD] and lines == []
    assert [i for i, _ in DatasetReader(damaged).iter_samples(on_error="raise")] == list(range(n))   # bytes read


def test_a_shard_that_does_not_open_is_skipped_whole_with_one_line(damaged, tmp_path, caplog):
    import shutil

    root = shutil.copytree(damaged, tmp_path / "ds")
    reader = DatasetReader(root)
    gone = reader.manifest["shards"][0]
    (root / SHARDS_DIR / gone["name"]).unlink()
    with pytest.raises(FileNotFoundError):
        list(reader.iter_samples())
    got, lines = streamed(root, "warn", caplog, shards=[0, 2])
    first = reader.manifest["shards"][2]["first_sample"]
    assert got == list(range(first, first + reader.manifest["shards"][2]["samples"]))
    assert len(lines) == 1 and gone["name"] in lines[0] and "every sample in it" in lines[0]


def test_a_policy_is_one_of_three(damaged):
    with pytest.raises(ArgumentError, match="on_error must be one of"):
        list(DatasetReader(damaged).iter_samples(on_error="ignore"))
    with pytest.raises(ArgumentError, match="on_error must be one of"):
        ItemOptions(on_error="quiet")


def test_the_stream_skips_a_sample_that_does_not_decode_and_map_style_datasets_refuse(damaged, caplog):
    torchdata = pytest.importorskip("htdata.read.torchdata")
    with pytest.raises(DatasetError, match="rgb.jpg"):
        list(torchdata.TactileStream(damaged))
    frames = torchdata.TactileFrameDataset(damaged).items          # (sample, hand) of every item
    bad_items = int((frames[:, 0] == BAD).sum())
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="htdata.read"):
        items = list(torchdata.TactileStream(damaged, options=ItemOptions(on_error="warn")))
    assert bad_items >= 1 and len(items) == len(frames) - bad_items
    assert BAD not in {int(i["index"]) for i in items} and len(caplog.records) == 1
    for kind in (torchdata.TactileFrameDataset, torchdata.TactileWindowDataset):
        with pytest.raises(ArgumentError, match="map-style.*TactileStream"):
            kind(damaged, options=ItemOptions(on_error="skip"))
