"""PyTorch datasets over a committed dataset (docs/FORMAT.md "Reader / torch").

- TactileFrameDataset: one item per (frame, hand present), map-style.
- TactileWindowDataset: one item per (frame T, hand) with T >= window-1,
  frames T-window+1..T of the same episode stacked. Frames T < window-1 have
  no full window and are NOT items (no padding); windows never cross episodes.
- TactileStream: IterableDataset reading shards front to back; shards are
  split across DataLoader workers and DDP ranks deterministically.

Every dataset takes one `options=ItemOptions(...)` (htdata/read/itemoptions.py: its fields, documented
there once, below as `field=`); the old keywords warn until htdata/_moved.py's REMOVED_IN.

Which samples: `frames="paired"` (default) = samples with the hand's map AND
an RGB frame, what the HandTouch stages train on; `frames="tactile"` adds
the tactile-only samples of glove-only recordings (e.g. for stage-1
tokeniser training): their RGB is zeros and `has_rgb` is False. RGB-only
samples (RGB frames without tactile, format 3) are never items: there is
no map to learn from.

Where maps come from (`maps_from`, htdata/read/rawstream.py `MapServing`):
"best" (default) renders each map from the sample's stored raw glove row
under its recorded calibration when the dataset stores no maps ([tactile]
maps = "raw": always rendered, "stored" is an error), or has raw rows and was
rasterised in nearest mode (a gather of the exact normalised values, ~1.4x
faster than decoding the EXR on the sample data: `make bench`, section "maps
from raw rows"); otherwise, and with "stored", the stored EXR is decoded
(values rounded to half, <= 2.4e-4 away). "raw" insists on raw rows. The old
keyword `map_source=` ("auto" = "best") still works, with a DeprecationWarning.

What an item carries (htdata/read/torchitems.py): `members=("tactile",)`
skips the RGB decode (stage-1 tokeniser training), `members=("rgb",)` the
map; `constants="once"` (frame datasets and streams) ships per-layout
constants once (`dataset.constants()`, rebuilt on the device by
`expand_batch`) and packs the ids into one `ids` tensor.

Every dataset's options take `version=N` to read a committed older version (default:
the current one). Each dataset holds a DatasetReader whose file handles open lazily per
process, so DataLoader workers (fork or spawn) each open their own files.
Item tensors: tactile (1,224,224) f32, coverage (1,224,224) f32, regions
(224,224) u8 part ids, rgb (3,224,224) u8 (or f32 in [0,1] with
rgb_float=True), hand (0 left, 1 right), task / scene (positions in the
manifest's lists), episode (position in episodes.jsonl), frame, index
(global sample index).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

try:
    import torch
except ModuleNotFoundError as exc:   # the data core installs without torch
    raise ModuleNotFoundError(f"{__name__} needs torch: pip install 'htdata[torch]' (torch==2.13.0)") from exc
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from htdata._moved import folded_keywords, moved_name, renamed_keyword
from htdata.errors import ArgumentError
from htdata.format.canvas import CANVAS
from htdata.format.mapstorage import hand_present, has_hand
from htdata.format.table import HANDS, RGB_MEMBER, SIZE_FIELDS
from htdata.read import keys
from htdata.read.itemoptions import FIELDS, ItemOptions, item_options, keywords_as_options, streamed_only
from htdata.read.onerror import READ_ERRORS, SkipPolicy
from htdata.read.rawstream import MAP_SOURCE_WORDS
from htdata.read.reader import DatasetReader
from htdata.read.torchitems import ItemBuilder, ItemConstants

HAND_NAMES = HANDS   # hand id -> name (HAND_IDS inverted: left=0, right=1)
# The datasets' signatures before `options=` (their keywords warn until htdata/_moved.py's REMOVED_IN)
_OLD_FRAME_ARGS = ("split", "part", "hands", "rgb_float", "version", "frames", "maps_from", "members", "constants")
_OLD_WINDOW_ARGS = _OLD_FRAME_ARGS[:-1]
_OLD_STREAM_ARGS = _OLD_FRAME_ARGS[:4] + ("shuffle_seed",) + _OLD_FRAME_ARGS[4:] + ("on_error",)


def _tactile_present(rows: np.ndarray, hand: str, frames: str = "paired") -> np.ndarray:
    present = hand_present(rows, hand)   # its map stored, or rendered from its raw rows
    return present & (rows[SIZE_FIELDS[RGB_MEMBER]] > 0) if frames == "paired" else present


def shuffled_indices(n: int, seed: int, epoch: int) -> np.ndarray:
    """A permutation of range(n) that depends only on (seed, epoch).

    Args:
        n: how many positions (>= 0).
        seed: the run's seed (>= 0).
        epoch: the epoch (>= 0): each epoch gets its own permutation.
    """
    if n < 0 or seed < 0 or epoch < 0:
        raise ArgumentError(f"n, seed and epoch must be >= 0 (got {n}, {seed}, {epoch})")
    return np.random.default_rng([seed, epoch]).permutation(n)


def _frame_items(reader: DatasetReader, indices: np.ndarray, hands: tuple[str, ...],
                 frames: str = "paired") -> np.ndarray:
    """(N,2) int64 [sample index, hand id] for each selected sample with that hand, sample-major."""
    rows = reader.index[indices] if len(indices) else np.zeros(0, reader.index.dtype)
    cols = []
    for hand in HANDS:
        present = _tactile_present(rows, hand, frames) if hand in hands else np.zeros(len(rows), bool)
        cols.append(present)
    present = np.stack(cols, axis=1)  # (N, 2)
    if frames == "paired" and not present.any():
        _explain_no_pairs(reader, rows, hands)
    sample_pos, hand_ids = np.nonzero(present)  # row-major: left before right per sample
    return np.stack([indices[sample_pos], hand_ids], axis=1).astype(np.int64)


def _explain_no_pairs(reader: DatasetReader, rows: np.ndarray, hands: tuple[str, ...]) -> None:
    """frames="paired" found nothing: if tactile frames are there (a glove-only dataset), say so, not length 0."""
    tactile = sum(int(_tactile_present(rows, h, "tactile").sum()) for h in hands)
    if tactile:
        raise ArgumentError(f"{reader.root}: none of the {len(rows)} selected samples pairs an RGB frame with "
                            f"{'/'.join(hands)} tactile ({tactile} hand frames have tactile only: a glove-only "
                            f"dataset?); pass options=ItemOptions(frames=\"tactile\") for tactile-only items")


class _ItemDataset(Dataset):
    """Map-style dataset over `self.items` rows, built by an `ItemBuilder`."""

    _builder: ItemBuilder
    items: np.ndarray

    @property
    def reader(self) -> DatasetReader:
        """The DatasetReader of the version the items come from."""
        return self._builder.reader

    def __len__(self) -> int:
        return len(self.items)

    def constants(self) -> ItemConstants:
        """Per-layout constants for batches of constants="once" items (`expand_batch`)."""
        return self._builder.constants()


class TactileFrameDataset(_ItemDataset):
    """One item per (frame, hand present) of the selected split part.

    Args:
        root: the dataset folder or URL.
        options: which samples, which version, what an item carries (htdata.read.itemoptions.ItemOptions;
            None: its defaults). Its `on_error` must be "raise".

    Raises:
        ArgumentError: `options` is not an ItemOptions or asks to skip samples; no sample selected pairs
            an RGB frame with a map under frames="paired" while tactile-only ones exist.
    """

    @renamed_keyword("map_source", "maps_from", MAP_SOURCE_WORDS)
    @folded_keywords("options", keywords_as_options, FIELDS, _OLD_FRAME_ARGS)
    def __init__(self, root, *, options: ItemOptions | None = None):
        o = self.options = streamed_only(item_options(options), "TactileFrameDataset")
        self.hands = o.hands
        self._builder = ItemBuilder(root, o)
        reader = self._builder.reader
        self.items = _frame_items(reader, reader.sample_indices(o.split, o.part), self.hands, o.frames)

    def __getitem__(self, i: int) -> dict:
        index, hand_id = self.items[i].tolist()
        return self._builder.frame_item(index, HAND_NAMES[hand_id])


class TactileWindowDataset(_ItemDataset):
    """Items for frames T >= window-1: tactile (window,1,224,224), rgb (window,3,224,224).

    frame / index are stacked (window,); coverage, regions, hand, task, scene,
    episode are the same for every frame of a window and given once.

    Args:
        root: the dataset folder or URL.
        window: frames per item (>= 1), consecutive samples of one episode ending at frame T.
        options: which samples, which version, what an item carries (htdata.read.itemoptions.ItemOptions;
            None: its defaults). Its `constants` must be "item" (a window carries its constants), its
            `on_error` "raise".

    Raises:
        ArgumentError: `window` < 1; `options` is not an ItemOptions, or its constants / on_error as above.
    """

    @renamed_keyword("map_source", "maps_from", MAP_SOURCE_WORDS)
    @folded_keywords("options", keywords_as_options, FIELDS, _OLD_WINDOW_ARGS)
    def __init__(self, root, window: int = 3, *, options: ItemOptions | None = None):
        if window < 1:
            raise ArgumentError(f"window must be >= 1, got {window}")
        o = self.options = item_options(options)
        if o.constants != "item":
            raise ArgumentError(f"TactileWindowDataset items carry their constants: options.constants must be "
                                f"'item', got {o.constants!r}")
        streamed_only(o, "TactileWindowDataset")
        self.window = window
        self.hands = o.hands
        frames = o.frames
        self._builder = ItemBuilder(root, o)
        reader = self._builder.reader
        ends = []
        for ep_pos in reader.episode_positions(o.split, o.part):
            first, n = reader.episode_range(ep_pos)
            if n >= window:
                ends.append(np.arange(first + window - 1, first + n, dtype=np.int64))
        end_idx = np.concatenate(ends) if ends else np.zeros(0, np.int64)
        items = _frame_items(reader, end_idx, self.hands, frames)
        # keep a window only if its hand is present in every frame of it (an RGB-only sample breaks it)
        if len(items):
            offsets = np.arange(-(window - 1), 1)
            at = items[:, :1] + offsets[None, :]
            cols = np.stack([_tactile_present(reader.index, h, frames) for h in HANDS], 1)
            present = cols[at, items[:, 1:2]]
            items = items[present.all(axis=1)]
        self.items = items

    def __getitem__(self, i: int) -> dict:
        end, hand_id = self.items[i].tolist()
        hand = HAND_NAMES[hand_id]
        builder, w = self._builder, self.window
        tactile = np.empty((w, 1, CANVAS, CANVAS), np.float32) if builder.wants_tactile else None
        rgb = builder.empty_rgb(w)   # frames decode straight into the stacked buffers
        for k, j in enumerate(range(end - w + 1, end + 1)):
            row, t_map = builder.read_frame(j, hand, None if rgb is None else rgb[k])
            if tactile is not None:
                tactile[k, 0] = t_map
        out = builder.put_members(builder.ids(row, end, hand), tactile, rgb)
        out[keys.FRAME] = torch.from_numpy(np.arange(row.frame - w + 1, row.frame + 1, dtype=np.int64))
        out[keys.INDEX] = torch.from_numpy(np.arange(end - w + 1, end + 1, dtype=np.int64))
        return out


def _dist_rank_world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


def shards_for_consumer(n_shards: int, consumer: int, consumers: int, seed: int | None, epoch: int) -> list[int]:
    """Shards read by one (rank, worker): a deterministic (optionally shuffled) round robin.

    Args:
        n_shards: shards in the version.
        consumer: this consumer's position, rank * num_workers + worker.
        consumers: world size * num_workers.
        seed: shuffle the shard order with (seed, epoch) (None: file order).
        epoch: the epoch the order is for.
    """
    order = np.arange(n_shards) if seed is None else shuffled_indices(n_shards, seed, epoch)
    return [int(s) for s in order[consumer::consumers]]


class TactileStream(IterableDataset):
    """Sequential frame items, reading each shard front to back.

    Shards are dealt round robin over rank*num_workers+worker consumers. With
    `shuffle_seed` the shard order is permuted per epoch (`set_epoch`). If
    there are fewer shards than consumers, some consumers yield nothing.

    Args:
        root: the dataset folder or URL.
        options: which samples, which version, what an item carries (htdata.read.itemoptions.ItemOptions;
            None: its defaults); with `on_error` "warn" or "skip" a shard that does not open is skipped whole.
        shuffle_seed: permute the shard order per epoch with this seed (None: file order).

    Raises:
        ArgumentError: `options` is not an ItemOptions.
    """

    @renamed_keyword("map_source", "maps_from", MAP_SOURCE_WORDS)
    @folded_keywords("options", keywords_as_options, FIELDS, _OLD_STREAM_ARGS)
    def __init__(self, root, *, options: ItemOptions | None = None, shuffle_seed: int | None = None):
        o = self.options = item_options(options)
        self.hands = o.hands
        self.frames = o.frames
        self._builder = ItemBuilder(root, o)
        reader = self._builder.reader
        selected = np.zeros(len(reader), bool)
        selected[reader.sample_indices(o.split, o.part)] = True
        self._selected = selected
        self.shuffle_seed = shuffle_seed
        self.epoch = 0

    @property
    def reader(self) -> DatasetReader:
        """The DatasetReader of the version the items come from."""
        return self._builder.reader

    def constants(self) -> ItemConstants:
        """Per-layout constants for batches of constants="once" items (`expand_batch`)."""
        return self._builder.constants()

    def set_epoch(self, epoch: int) -> None:
        """Args: epoch: the epoch whose shard order the next iteration reads (with `shuffle_seed`)."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        idx = np.nonzero(self._selected)[0]
        return len(_frame_items(self.reader, idx, self.hands, self.frames))

    def my_shards(self) -> list[int]:
        """The shards this process reads (its rank and DataLoader worker), those without a selected sample left out."""
        rank, world = _dist_rank_world()
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        consumer, consumers = rank * workers + worker, world * workers
        n = len(self.reader.manifest["shards"])
        shards = shards_for_consumer(n, consumer, consumers, self.shuffle_seed, self.epoch)
        # skip shards holding no selected sample without opening them
        keep = []
        for s in shards:
            entry = self.reader.manifest["shards"][s]
            if self._selected[entry["first_sample"]:entry["first_sample"] + entry["samples"]].any():
                keep.append(s)
        return keep

    def __iter__(self) -> Iterator[dict]:
        return self.iter_shards(self.my_shards())

    def iter_shards(self, shards: list[int]) -> Iterator[dict]:
        """Items of the selected samples of `shards`, in order (what __iter__ yields for its shards).

        Args:
            shards: positions in the manifest's shard list.
        """
        builder, reader = self._builder, self.reader
        wanted = builder.suffixes(self.hands)
        policy = SkipPolicy(self.options.on_error)     # the reader skips what does not read, this what does not decode
        for index, members in reader.iter_samples(shards, suffixes=wanted, on_error=self.options.on_error):
            if not self._selected[index]:
                continue
            present = ((lambda h: has_hand(members, h)) if builder.wants_tactile else   # maps not read: the index says
                       (lambda h: bool(hand_present(reader.index[index:index + 1], h)[0])))
            hands = [h for h in HAND_NAMES if h in self.hands and present(h)]
            paired = reader.index[index][SIZE_FIELDS[RGB_MEMBER]] > 0   # the JPEG may not be read (members)
            if not hands or (self.frames == "paired" and not paired):
                continue
            row = reader.row(index)
            rgb = builder.empty_rgb(len(hands))   # JPEG decoded once for both hands
            try:
                maps = builder.decode_into(members, hands, f"{reader.root}: {reader.key(index)}", rgb, row.episode)
            except READ_ERRORS as exc:
                if not policy.skips(exc, f"sample {index} ({reader.key(index)})"):
                    raise
                continue
            for k, hand in enumerate(hands):
                yield builder.put_members(builder.ids(row, index, hand), None if maps[k] is None else maps[k][None],
                                          None if rgb is None else rgb[k])


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
