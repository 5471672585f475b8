"""PyTorch datasets over a committed dataset (docs/FORMAT.md "Reader / torch").

- TactileFrameDataset: one item per (frame, hand present), map-style.
- TactileWindowDataset: one item per (frame T, hand) with T >= window-1,
  frames T-window+1..T of the same episode stacked. Frames T < window-1 have
  no full window and are NOT items (no padding); windows never cross episodes.
- TactileStream: IterableDataset reading shards front to back; shards are
  split across DataLoader workers and DDP ranks deterministically.

Which samples: `frames="paired"` (default) = samples with the hand's map AND
an RGB frame, what the HandTouch stages train on; `frames="tactile"` adds
the tactile-only samples of glove-only recordings (e.g. for stage-1
tokeniser training): their RGB is zeros and `has_rgb` is False. RGB-only
samples (RGB frames without tactile, format 3) are never items: there is
no map to learn from.

Where maps come from: `map_source="auto"` (default) renders each map from the
sample's stored raw glove row under its recorded calibration when the
dataset stores no maps ([tactile] maps = "raw": always rendered, "stored" is
an error), or has raw rows and was rasterised in nearest mode (a gather of the
exact normalised values, ~1.4x faster than decoding the EXR on the sample
data: `make bench`, section "maps from raw rows"); otherwise, and with
`map_source="stored"`, the stored EXR is decoded (values rounded to half,
<= 2.4e-4 away). `map_source="raw"` insists on raw rows.

Every dataset takes `version=N` to read a committed older version (default:
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

import cv2
import numpy as np

try:
    import torch
except ModuleNotFoundError as exc:   # the data core installs without torch
    raise ModuleNotFoundError(f"{__name__} needs torch: pip install 'htdata[torch]' (torch==2.13.0)") from exc
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from htdata.read import keys
from htdata.format.table import (CANVAS, HANDS, JSON_MEMBER, MEMBER_ORDER, RGB_MEMBER, SIZE_FIELDS, decode_member, raw_member,
                           tactile_member)
from htdata.read.keys import HAND_IDS
from htdata.format.mapstorage import has_hand, hand_present
from htdata.read.rawstream import MAP_SOURCES, RawMapRenderer, serves_maps_from_raw  # noqa: F401  (MAP_SOURCES: a name of this module)
from htdata.read.reader import DatasetReader, SampleRow

HAND_NAMES = HANDS   # hand id -> name (HAND_IDS inverted: left=0, right=1)


FRAME_KINDS = ("paired", "tactile")
_RGB_POS = MEMBER_ORDER.index(RGB_MEMBER)   # in SampleRow.sizes


def _tactile_present(rows: np.ndarray, hand: str, frames: str = "paired") -> np.ndarray:
    present = hand_present(rows, hand)   # its map stored, or rendered from its raw rows
    return present & (rows[SIZE_FIELDS[RGB_MEMBER]] > 0) if frames == "paired" else present


def _check_frames(frames: str) -> str:
    if frames not in FRAME_KINDS:
        raise ValueError(f"frames must be one of {FRAME_KINDS}, got {frames!r}")
    return frames


def shuffled_indices(n: int, seed: int, epoch: int) -> np.ndarray:
    """A permutation of range(n) that depends only on (seed, epoch)."""
    if n < 0 or seed < 0 or epoch < 0:
        raise ValueError(f"n, seed and epoch must be >= 0 (got {n}, {seed}, {epoch})")
    return np.random.default_rng([seed, epoch]).permutation(n)


def _check_hands(hands) -> tuple[str, ...]:
    hands = tuple(hands)
    if not hands or any(h not in HAND_IDS for h in hands) or len(set(hands)) != len(hands):
        raise ValueError(f"hands must be a non-empty subset of ('left', 'right'), got {hands}")
    return hands


def _long(value: int) -> torch.Tensor:
    # 0-d int64 via numpy: ~3x cheaper than torch.tensor(value) per call.
    return torch.from_numpy(np.array(value, dtype=np.int64))


class _ItemBuilder:
    """Decodes (sample, hand) into item tensors with the fewest copies and no torch kernels.

    Items are assembled in numpy and wrapped with torch.from_numpy: torch ops
    such as stack / div run on torch's OpenMP pool, whose threads spin against
    other processes on a shared machine (measured: torch.stack of three
    (1,224,224) maps took 6-19 ms instead of 0.02 ms). The json member is not
    read: every id an item carries comes from index.npy and episodes.jsonl.
    """

    def __init__(self, root, rgb_float: bool, version: int | None = None, map_source: str = "auto"):
        self.reader = DatasetReader(root, version=version)
        self.rgb_float = rgb_float
        self.from_raw = serves_maps_from_raw(self.reader.manifest, map_source, where=str(self.reader.root))
        self.strict_raw = map_source == "raw"
        self.renderer = RawMapRenderer(self.reader) if self.from_raw else None
        self._task_ids = {t: i for i, t in enumerate(self.reader.manifest["tasks"])}
        self._scene_ids = {s: i for i, s in enumerate(self.reader.manifest["scenes"])}
        self._coverage: dict[str, torch.Tensor] = {}
        self._regions: torch.Tensor | None = None

    def coverage(self, layout_id: str) -> torch.Tensor:
        if layout_id not in self._coverage:
            cov = self.reader.coverage(layout_id).astype(np.float32)
            self._coverage[layout_id] = torch.from_numpy(cov)[None]
        return self._coverage[layout_id]

    def regions(self) -> torch.Tensor:
        if self._regions is None:
            self._regions = torch.from_numpy(np.ascontiguousarray(self.reader.region_map))
        return self._regions

    def empty_rgb(self, n: int) -> np.ndarray:
        """(n,3,224,224) rgb buffer (u8, or f32 with rgb_float) to decode into."""
        return np.empty((n, 3, CANVAS, CANVAS), np.float32 if self.rgb_float else np.uint8)

    def put_rgb(self, out: np.ndarray, rgb_hwc: np.ndarray) -> None:
        """HWC uint8 -> CHW in `out` (scaled to [0,1] when out is float).

        cv2.split writes straight into the three planes (~4x faster than a
        numpy transpose copy); the pointer check guards against a binding that
        allocated new planes instead.
        """
        planes = out if out.dtype == np.uint8 else np.empty(out.shape, np.uint8)
        written = cv2.split(rgb_hwc, [planes[0], planes[1], planes[2]])
        if any(w.ctypes.data != p.ctypes.data for w, p in zip(written, planes)):
            planes[...] = rgb_hwc.transpose(2, 0, 1)
        if planes is not out:
            np.divide(planes, np.float32(255.0), out=out, dtype=np.float32)

    def suffixes(self, hands) -> tuple[str, ...]:
        """Members an item of these hands reads."""
        maps = tuple(tactile_member(h) for h in hands)
        return (RGB_MEMBER, JSON_MEMBER, *maps, *(raw_member(h) for h in hands)) if self.from_raw else (RGB_MEMBER, *maps)

    def tactile_map(self, members: dict[str, bytes], hand: str, episode: int, where: str) -> np.ndarray:
        if self.from_raw and raw_member(hand) in members:
            return self.renderer.render(episode, hand, members, where)
        if self.strict_raw:
            raise KeyError(f"{where} has no raw {hand} rows (map_source='raw')")
        suffix = tactile_member(hand)
        if suffix not in members:
            raise KeyError(f"{where} has no {hand} tactile map")
        return decode_member(suffix, members[suffix], where)

    def decode_into(self, members: dict[str, bytes], hands, where: str, rgb_out, episode: int) -> list[np.ndarray]:
        """Decode the JPEG once into each hand's rgb buffer (zeros when the sample has none); each hand's map."""
        if RGB_MEMBER in members:
            rgb = decode_member(RGB_MEMBER, members[RGB_MEMBER], where)
        else:
            rgb = np.zeros((CANVAS, CANVAS, 3), np.uint8)
        maps = []
        for k, (hand, r_out) in enumerate(zip(hands, rgb_out)):
            maps.append(self.tactile_map(members, hand, episode, where))
            if k == 0:
                self.put_rgb(r_out, rgb)
            else:
                r_out[...] = rgb_out[0]   # each item owns its rgb: a plain copy of the first
        return maps

    def read_frame(self, index: int, hand: str, rgb_out: np.ndarray) -> tuple[SampleRow, np.ndarray]:
        """Read + decode sample `index` for `hand`: rgb into `rgb_out` (3,224,224); returns (row, map)."""
        reader = self.reader
        row, key, members = reader.read_sample(index, suffixes=self.suffixes((hand,)))
        return row, self.decode_into(members, (hand,), f"{reader.root}: {key}", [rgb_out], row.episode)[0]

    def ids(self, row: SampleRow, index: int, hand: str) -> dict:
        ep = self.reader.episodes[row.episode]
        return {
            keys.COVERAGE: self.coverage(ep["layouts"][hand]),
            keys.REGIONS: self.regions(),
            keys.HAND: _long(HAND_IDS[hand]),
            keys.TASK: _long(self._task_ids[ep["task"]]),
            keys.SCENE: _long(self._scene_ids[ep["scene"]]),
            keys.EPISODE: _long(row.episode),
            keys.FRAME: _long(row.frame),
            keys.INDEX: _long(index),
            keys.HAS_RGB: torch.from_numpy(np.array(row.sizes[_RGB_POS] > 0)),
        }

    def frame_item(self, index: int, hand: str) -> dict:
        rgb = self.empty_rgb(1)[0]
        row, tactile = self.read_frame(index, hand, rgb)
        item = self.ids(row, index, hand)
        item[keys.TACTILE] = torch.from_numpy(tactile[None])   # decoded map is a fresh array: no copy
        item[keys.RGB] = torch.from_numpy(rgb)
        return item


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
        raise ValueError(f"{reader.root}: none of the {len(rows)} selected samples pairs an RGB frame with "
                         f"{'/'.join(hands)} tactile ({tactile} hand frames have tactile only: a glove-only "
                         f"dataset?); pass frames=\"tactile\" for tactile-only items")


class _ItemDataset(Dataset):
    """Map-style dataset over `self.items` rows, built by an `_ItemBuilder`."""

    _builder: "_ItemBuilder"
    items: np.ndarray

    @property
    def reader(self) -> DatasetReader:
        return self._builder.reader

    def __len__(self) -> int:
        return len(self.items)


class TactileFrameDataset(_ItemDataset):
    """One item per (frame, hand present) of the selected split part."""

    def __init__(self, root, split: str | None = None, part: str | None = None,
                 hands=HANDS, rgb_float: bool = False, version: int | None = None, frames: str = "paired",
                 map_source: str = "auto"):
        self.hands = _check_hands(hands)
        self._builder = _ItemBuilder(root, rgb_float, version, map_source)
        reader = self._builder.reader
        self.items = _frame_items(reader, reader.sample_indices(split, part), self.hands, _check_frames(frames))

    def __getitem__(self, i: int) -> dict:
        index, hand_id = self.items[i].tolist()
        return self._builder.frame_item(index, HAND_NAMES[hand_id])


class TactileWindowDataset(_ItemDataset):
    """Items for frames T >= window-1: tactile (window,1,224,224), rgb (window,3,224,224).

    frame / index are stacked (window,); coverage, regions, hand, task, scene,
    episode are the same for every frame of a window and given once.
    """

    def __init__(self, root, window: int = 3, split: str | None = None, part: str | None = None,
                 hands=HANDS, rgb_float: bool = False, version: int | None = None, frames: str = "paired",
                 map_source: str = "auto"):
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self.window = window
        self.hands = _check_hands(hands)
        self._builder = _ItemBuilder(root, rgb_float, version, map_source)
        reader = self._builder.reader
        ends = []
        for ep_pos in reader.episode_positions(split, part):
            first, n = reader.episode_range(ep_pos)
            if n >= window:
                ends.append(np.arange(first + window - 1, first + n, dtype=np.int64))
        end_idx = np.concatenate(ends) if ends else np.zeros(0, np.int64)
        items = _frame_items(reader, end_idx, self.hands, _check_frames(frames))
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
        tactile = np.empty((w, 1, CANVAS, CANVAS), np.float32)
        rgb = builder.empty_rgb(w)   # frames decode straight into the stacked buffers
        for k, j in enumerate(range(end - w + 1, end + 1)):
            row, tactile[k, 0] = builder.read_frame(j, hand, rgb[k])
        out = builder.ids(row, end, hand)
        out[keys.TACTILE] = torch.from_numpy(tactile)
        out[keys.RGB] = torch.from_numpy(rgb)
        out[keys.FRAME] = torch.from_numpy(np.arange(row.frame - w + 1, row.frame + 1, dtype=np.int64))
        out[keys.INDEX] = torch.from_numpy(np.arange(end - w + 1, end + 1, dtype=np.int64))
        return out


def _dist_rank_world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


def shards_for_consumer(n_shards: int, consumer: int, consumers: int, seed: int | None, epoch: int) -> list[int]:
    """Shards read by one (rank, worker): a deterministic (optionally shuffled) round robin."""
    order = np.arange(n_shards) if seed is None else shuffled_indices(n_shards, seed, epoch)
    return [int(s) for s in order[consumer::consumers]]


class TactileStream(IterableDataset):
    """Sequential frame items, reading each shard front to back.

    Shards are dealt round robin over rank*num_workers+worker consumers. With
    `shuffle_seed` the shard order is permuted per epoch (`set_epoch`). If
    there are fewer shards than consumers, some consumers yield nothing.
    """

    def __init__(self, root, split: str | None = None, part: str | None = None,
                 hands=HANDS, rgb_float: bool = False,
                 shuffle_seed: int | None = None, version: int | None = None, frames: str = "paired",
                 map_source: str = "auto"):
        self.hands = _check_hands(hands)
        self.frames = _check_frames(frames)
        self._builder = _ItemBuilder(root, rgb_float, version, map_source)
        reader = self._builder.reader
        selected = np.zeros(len(reader), bool)
        selected[reader.sample_indices(split, part)] = True
        self._selected = selected
        self.shuffle_seed = shuffle_seed
        self.epoch = 0

    @property
    def reader(self) -> DatasetReader:
        return self._builder.reader

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        idx = np.nonzero(self._selected)[0]
        return len(_frame_items(self.reader, idx, self.hands, self.frames))

    def my_shards(self) -> list[int]:
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
        """Items of the selected samples of `shards`, in order (what __iter__ yields for its shards)."""
        builder, reader = self._builder, self.reader
        wanted = builder.suffixes(self.hands)
        for index, members in reader.iter_samples(shards, suffixes=wanted):
            if not self._selected[index]:
                continue
            hands = [h for h in HAND_NAMES if h in self.hands and has_hand(members, h)]
            if not hands or (self.frames == "paired" and RGB_MEMBER not in members):
                continue
            row = reader.row(index)
            rgb = builder.empty_rgb(len(hands))   # JPEG decoded once for both hands
            maps = builder.decode_into(members, hands, f"{reader.root}: {reader.key(index)}", rgb, row.episode)
            for k, hand in enumerate(hands):
                item = builder.ids(row, index, hand)
                item[keys.TACTILE] = torch.from_numpy(maps[k][None])
                item[keys.RGB] = torch.from_numpy(rgb[k])
                yield item
