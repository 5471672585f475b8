"""The torch datasets refuse a split `htdata validate` would fail: overlapping parts, or a file edited
after its version was committed (sha256 mismatch). Before issue 18 they trained on either silently."""

import pytest

from htdata.curate.split import write_split
from htdata.errors import HtdataError
from htdata.read.itemoptions import ItemOptions
from htdata.read.torchdata import TactileFrameDataset
from tests.factories import commit_split, write_synthetic_dataset

EPISODES = [{"episode_id": f"ep_{i}", "task": "pour" if i % 2 else "wipe", "scene": "lab", "hands": ("right",),
             "num_frames": 3} for i in range(6)]


def test_overlapping_split_is_refused_at_open(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    commit_split(root, "leaky", {"train": ["ep_0", "ep_1", "ep_2"], "test": ["ep_2", "ep_3"], "ood": []})
    with pytest.raises(HtdataError, match=r"episode 'ep_2' is in both test and train"):
        TactileFrameDataset(root, options=ItemOptions(split="leaky", part="train"))


def test_split_edited_after_commit_is_refused_at_open(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES)
    write_split(root, ["pour"], name="main", seed=0)
    assert len(TactileFrameDataset(root, options=ItemOptions(split="main", part="train"))) > 0
    from htdata.read.reader import DatasetReader

    path = root / DatasetReader(root).manifest["splits"]["main"]["file"]
    path.write_text(path.read_text().replace('"ep_1"', '"ep_0"', 1))
    with pytest.raises(HtdataError, match=r"main\.json: sha256 differs from version 2's manifest"):
        TactileFrameDataset(root, options=ItemOptions(split="main", part="train"))
