"""`htdata.open(...)` -> `Dataset`: a DatasetReader with its torch datasets one attribute away.

    ds = htdata.open("data/dataset")
    train = ds.torch.frames(split="main", part="train")      # TactileFrameDataset
    clips = ds.torch.windows(window=3, split="main", part="train")

Each method builds the dataset for the reader's own root and version and
passes every other keyword on (see htdata/read/torchdata.py and torchglove.py).

Imports inside functions: torch is an optional extra (`pip install 'htdata[torch]'`),
so the torch datasets are imported when one is asked for, never when a reader opens.
"""

from __future__ import annotations

from htdata.read.reader import DatasetReader


class Dataset(DatasetReader):
    """What `htdata.open` returns: the reader of one version, plus `.torch` (its torch datasets).

    (The plain DatasetReader does not know the torch datasets: they are built on it.)
    """

    @property
    def torch(self) -> "TorchDatasets":
        """The torch datasets of this version: `ds.torch.frames(split=..., part=...)` (needs htdata[torch])."""
        return TorchDatasets(self.root, self.version)


class TorchDatasets:
    """Factories of the torch datasets over one version of one dataset."""

    def __init__(self, root: str, version: int | None):
        self.root = root
        self.version = version

    def frames(self, **kwargs):
        """TactileFrameDataset: one item per (frame, hand present)."""
        from htdata.read.torchdata import TactileFrameDataset

        return TactileFrameDataset(self.root, version=self.version, **kwargs)

    def windows(self, window: int = 3, **kwargs):
        """TactileWindowDataset: `window` consecutive frames of one episode per item."""
        from htdata.read.torchdata import TactileWindowDataset

        return TactileWindowDataset(self.root, window=window, version=self.version, **kwargs)

    def stream(self, **kwargs):
        """TactileStream: frames read shard by shard (an IterableDataset for large datasets)."""
        from htdata.read.torchdata import TactileStream

        return TactileStream(self.root, version=self.version, **kwargs)

    def glove_windows(self, window: int = 4, **kwargs):
        """GloveRateWindowDataset: the last `window` glove rows at the glove's own rate."""
        from htdata.read.torchglove import GloveRateWindowDataset

        return GloveRateWindowDataset(self.root, window=window, version=self.version, **kwargs)
