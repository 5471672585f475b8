"""PyTorch datasets over a committed dataset (DESIGN.md "Reader / torch").

- TactileFrameDataset: one item per (frame, hand present), map-style.
- TactileWindowDataset: one item per (frame T, hand) with T >= window-1,
  frames T-window+1..T of the same episode stacked. Frames T < window-1 have
  no full window and are NOT items (no padding); windows never cross episodes.
- TactileStream: IterableDataset reading shards front to back; shards are
  split across DataLoader workers and DDP ranks deterministically.

Each dataset holds a DatasetReader whose file handles open lazily per
process, so DataLoader workers (fork or spawn) each open their own files.
Item tensors: tactile (1,224,224) f32, coverage (1,224,224) f32, regions
(224,224) u8 part ids, rgb (3,224,224) u8 (or f32 in [0,1] with
rgb_float=True), hand (0 left, 1 right), task / scene (positions in the
manifest's lists), episode (position in episodes.jsonl), frame, index
(global sample index).
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from htdata.reader import DatasetReader

HAND_IDS = {"left": 0, "right": 1}


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


class _ItemBuilder:
    """Shared decoding of one (sample, hand) into tensors; caches maps per layout."""

    def __init__(self, root, rgb_float: bool):
        self.reader = DatasetReader(root)
        self.rgb_float = rgb_float
        self._task_ids = {t: i for i, t in enumerate(self.reader.manifest["tasks"])}
        self._scene_ids = {s: i for i, s in enumerate(self.reader.manifest["scenes"])}
        self._coverage: dict[str, torch.Tensor] = {}
        self._regions: torch.Tensor | None = None

    def hand_present(self, rows: np.ndarray, hand: str) -> np.ndarray:
        return rows[f"size_tactile_{hand}"] > 0

    def coverage(self, layout_id: str) -> torch.Tensor:
        if layout_id not in self._coverage:
            cov = self.reader.coverage(layout_id).astype(np.float32)
            self._coverage[layout_id] = torch.from_numpy(cov)[None]
        return self._coverage[layout_id]

    def regions(self) -> torch.Tensor:
        if self._regions is None:
            self._regions = torch.from_numpy(np.ascontiguousarray(self.reader.region_map))
        return self._regions

    def rgb(self, arr: np.ndarray) -> torch.Tensor:
        t = torch.from_numpy(np.ascontiguousarray(arr.transpose(2, 0, 1)))
        return t.float().div_(255.0) if self.rgb_float else t

    def frame_parts(self, index: int, hand: str, decoded: dict | None = None) -> dict:
        """Per-frame tensors (tactile, rgb) + ids of sample `index` for `hand`."""
        reader = self.reader
        if decoded is None:
            # decode only what this item needs (not the other hand's map)
            members = reader.sample(index)
            wanted = {k: v for k, v in members.items() if k in ("json", "rgb.jpg", f"tactile_{hand}.exr")}
            decoded = reader.decode(wanted, where=f"{reader.root}: {reader.key(index)}")
        if hand not in decoded["tactile"]:
            raise KeyError(f"{reader.root}: {reader.key(index)} has no {hand} tactile map")
        return {
            "tactile": torch.from_numpy(decoded["tactile"][hand])[None],
            "rgb": self.rgb(decoded["rgb"]),
        }

    def ids(self, index: int, hand: str) -> dict:
        row = self.reader.index[index]
        ep_pos = int(row["episode"])
        ep = self.reader.episodes[ep_pos]
        return {
            "coverage": self.coverage(ep["layouts"][hand]),
            "regions": self.regions(),
            "hand": torch.tensor(HAND_IDS[hand], dtype=torch.long),
            "task": torch.tensor(self._task_ids[ep["task"]], dtype=torch.long),
            "scene": torch.tensor(self._scene_ids[ep["scene"]], dtype=torch.long),
            "episode": torch.tensor(ep_pos, dtype=torch.long),
            "frame": torch.tensor(int(row["frame"]), dtype=torch.long),
            "index": torch.tensor(int(index), dtype=torch.long),
        }


def _frame_items(reader: DatasetReader, indices: np.ndarray, hands: tuple[str, ...]) -> np.ndarray:
    """(N,2) int64 [sample index, hand id] for each selected sample with that hand, sample-major."""
    rows = reader.index[indices] if len(indices) else np.zeros(0, reader.index.dtype)
    cols = []
    for hand in ("left", "right"):
        present = rows[f"size_tactile_{hand}"] > 0 if hand in hands else np.zeros(len(rows), bool)
        cols.append(present)
    present = np.stack(cols, axis=1)  # (N, 2)
    sample_pos, hand_ids = np.nonzero(present)  # row-major: left before right per sample
    return np.stack([indices[sample_pos], hand_ids], axis=1).astype(np.int64)


class TactileFrameDataset(Dataset):
    """One item per (frame, hand present) of the selected split part."""

    def __init__(self, root, split: str | None = None, part: str | None = None,
                 hands=("left", "right"), rgb_float: bool = False):
        self.hands = _check_hands(hands)
        self._builder = _ItemBuilder(root, rgb_float)
        reader = self._builder.reader
        self.items = _frame_items(reader, reader.sample_indices(split, part), self.hands)

    @property
    def reader(self) -> DatasetReader:
        return self._builder.reader

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict:
        index, hand_id = (int(v) for v in self.items[i])
        hand = ("left", "right")[hand_id]
        return {**self._builder.frame_parts(index, hand), **self._builder.ids(index, hand)}


class TactileWindowDataset(Dataset):
    """Items for frames T >= window-1: tactile (window,1,224,224), rgb (window,3,224,224).

    frame / index are stacked (window,); coverage, regions, hand, task, scene,
    episode are the same for every frame of a window and given once.
    """

    def __init__(self, root, window: int = 3, split: str | None = None, part: str | None = None,
                 hands=("left", "right"), rgb_float: bool = False):
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self.window = window
        self.hands = _check_hands(hands)
        self._builder = _ItemBuilder(root, rgb_float)
        reader = self._builder.reader
        ends = []
        for ep_pos in reader.episode_positions(split, part):
            first, n = reader.episode_range(ep_pos)
            if n >= window:
                ends.append(np.arange(first + window - 1, first + n, dtype=np.int64))
        end_idx = np.concatenate(ends) if ends else np.zeros(0, np.int64)
        items = _frame_items(reader, end_idx, self.hands)
        # keep a window only if its hand is present in every frame of it
        if len(items):
            offsets = np.arange(-(window - 1), 1)
            frames = items[:, :1] + offsets[None, :]
            cols = np.stack([reader.index["size_tactile_left"], reader.index["size_tactile_right"]], 1)
            present = cols[frames, items[:, 1:2]] > 0
            items = items[present.all(axis=1)]
        self.items = items

    @property
    def reader(self) -> DatasetReader:
        return self._builder.reader

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict:
        end, hand_id = (int(v) for v in self.items[i])
        hand = ("left", "right")[hand_id]
        frames = [self._builder.frame_parts(j, hand) for j in range(end - self.window + 1, end + 1)]
        out = self._builder.ids(end, hand)
        out["tactile"] = torch.stack([f["tactile"] for f in frames])
        out["rgb"] = torch.stack([f["rgb"] for f in frames])
        out["frame"] = torch.arange(int(out["frame"]) - self.window + 1, int(out["frame"]) + 1)
        out["index"] = torch.arange(end - self.window + 1, end + 1)
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
                 hands=("left", "right"), rgb_float: bool = False,
                 shuffle_seed: int | None = None):
        self.hands = _check_hands(hands)
        self._builder = _ItemBuilder(root, rgb_float)
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
        return len(_frame_items(self.reader, idx, self.hands))

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
        builder = self._builder
        for index, decoded in self.reader.iter_samples(self.my_shards(), decode=True):
            if not self._selected[index]:
                continue
            for hand in ("left", "right"):
                if hand in self.hands and hand in decoded["tactile"]:
                    yield {**builder.frame_parts(index, hand, decoded), **builder.ids(index, hand)}
