"""`htdata.open(...)` -> `Dataset`: a DatasetReader with its torch datasets one attribute away.

    ds = htdata.open("data/dataset")
    train = ds.torch.frames(split="main", part="train")      # TactileFrameDataset
    clips = ds.torch.windows(window=3, split="main", part="train")

Each method builds the dataset for the reader's own root and version: the keywords that are
ItemOptions' fields (htdata/read/itemoptions.py) become its `options=`, or an `options=` object
given gets the reader's version; the rest go on as they are (htdata/read/torchdata.py, torchglove.py).

Imports inside functions: torch is an optional extra (`pip install 'htdata[torch]'`),
so the torch datasets are imported when one is asked for, never when a reader opens.
"""

from __future__ import annotations

from htdata.read.itemoptions import FIELDS, item_options, keywords_as_options
from htdata.read.reader import DatasetReader


class Dataset(DatasetReader):
    """What `htdata.open` returns: the reader of one version, plus `.torch` (its torch datasets).

    (The plain DatasetReader does not know the torch datasets: they are built on it.)
    The version's records without its samples are `ds.meta` (htdata.read.metadata.DatasetMetadata).

    Args:
        root: the dataset root, a local path or an fsspec URL.
        validate_manifest: check the manifest against its schema.
        version: the version to open; None: the current one.
    """

    @property
    def torch(self) -> "TorchDatasets":
        """The torch datasets of this version: `ds.torch.frames(split=..., part=...)` (needs htdata[torch]).

        Returns:
            TorchDatasets over this reader's root and version.
        """
        return TorchDatasets(self.root, self.version)


class TorchDatasets:
    """Factories of the torch datasets over one version of one dataset.

    Args:
        root: the dataset root, a local path or an fsspec URL.
        version: the version every dataset built here reads (None: the current one).
    """

    def __init__(self, root: str, version: int | None):
        self.root = root
        self.version = version

    def _versioned(self, kwargs: dict) -> dict:
        """`kwargs` with their ItemOptions fields as one `options=` object reading this version.

        Args:
            kwargs: a method's keywords: ItemOptions fields, or `options=`, and the dataset's own.

        Returns:
            The keywords for the dataset: `options=` and its own.

        Raises:
            TypeError: `version=` given (the view reads its own version).
            ArgumentError: fields and `options=` together, or an `options=` that is not an ItemOptions.
        """
        if "version" in kwargs:
            raise TypeError(f"got multiple values for keyword argument 'version' (this view reads version "
                            f"{self.version}: open the dataset at the version wanted)")
        fields = {k: kwargs.pop(k) for k in FIELDS if k in kwargs}
        options = kwargs.pop("options", None)
        options = keywords_as_options(options, fields) if fields else item_options(options)
        return {**kwargs, "options": options.replace(version=self.version)}

    def frames(self, **kwargs):
        """TactileFrameDataset: one item per (frame, hand present).

        Args:
            **kwargs: TactileFrameDataset's other arguments (split, part, hands, members, ...).

        Returns:
            htdata.read.torchdata.TactileFrameDataset over this root and version.
        """
        from htdata.read.torchdata import TactileFrameDataset

        return TactileFrameDataset(self.root, **self._versioned(kwargs))

    def windows(self, window: int = 3, **kwargs):
        """TactileWindowDataset: `window` consecutive frames of one episode per item.

        Args:
            window: frames per item (T-window+1..T), never across an episode's start.
            **kwargs: TactileWindowDataset's other arguments (split, part, hands, members, ...).

        Returns:
            htdata.read.torchdata.TactileWindowDataset over this root and version.
        """
        from htdata.read.torchdata import TactileWindowDataset

        return TactileWindowDataset(self.root, window=window, **self._versioned(kwargs))

    def stream(self, **kwargs):
        """TactileStream: frames read shard by shard (an IterableDataset for large datasets).

        Args:
            **kwargs: TactileStream's other arguments (split, part, hands, shuffle_seed, ...).

        Returns:
            htdata.read.torchdata.TactileStream over this root and version.
        """
        from htdata.read.torchdata import TactileStream

        return TactileStream(self.root, **self._versioned(kwargs))

    def glove_windows(self, window: int = 4, **kwargs):
        """GloveRateWindowDataset: the last `window` glove rows at the glove's own rate.

        Args:
            window: glove rows per item, ending at the row paired with a frame.
            **kwargs: GloveRateWindowDataset's other arguments (split, part, hands, or options=).

        Returns:
            htdata.read.torchglove.GloveRateWindowDataset over this root and version.
        """
        from htdata.read.torchglove import GloveRateWindowDataset

        return GloveRateWindowDataset(self.root, window=window, **self._versioned(kwargs))
