"""TactileFrameDataset through a torch DataLoader at 1 and N worker processes: does reading scale?

Steady state, as training sees it: `persistent_workers=True`, one untimed
epoch first (worker start-up, imports, file handles), then one timed epoch
of shuffled items (seeded) in batches. 1 and N workers alternate `reps`
times; the speed-up is the median of the pairs. Maps come from the loaders'
default (`maps_from="best"`: rendered from raw rows where they render exactly) and,
for comparison, "stored" (the EXR decoded); then the items a tactile-only
step asks for (`members=("tactile",)`, `constants="once"`: no JPEG decoded,
per-layout constants not sent). `ipc_bytes_per_item` is what one item moves
from a worker to the training process (the tensors' bytes). Worker processes
take the DataLoader's default start method on this platform.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

from htdata.format.mapstorage import MapStorage
from htdata.read import keys
from htdata.read.itemoptions import ItemOptions
from htdata.read.metadata import DatasetMetadata
from htdata.read.torchdata import TactileFrameDataset

# (row label, maps_from, dataset keywords): full items as the trainer read them before #28, then tactile-only
VARIANTS = (("full", "best", {}), ("full", "stored", {}),
            ("tactile", "best", {"members": (keys.TACTILE,), "constants": "once"}))


def ipc_bytes(item: dict) -> int:
    """Bytes of the tensors of one item: what a DataLoader worker hands the training process."""
    return sum(v.numel() * v.element_size() for v in item.values() if torch.is_tensor(v))


def _epoch_rate(root: Path, workers: int, maps_from: str, items: int, batch_size: int, seed: int,
                options: dict | None = None) -> float:
    dataset = TactileFrameDataset(root, options=ItemOptions(maps_from=maps_from, **(options or {})))
    pick = np.random.default_rng(seed).permutation(len(dataset))[:items].tolist()
    loader = DataLoader(Subset(dataset, pick), batch_size=batch_size, shuffle=True, num_workers=workers,
                        persistent_workers=workers > 0, generator=torch.Generator().manual_seed(seed))
    for _ in loader:        # warm-up epoch: workers started, files opened
        pass
    t0 = time.perf_counter()
    n = sum(len(batch[keys.TACTILE]) for batch in loader)
    seconds = time.perf_counter() - t0
    del loader
    return n / seconds


def dataloader_rows(root: Path, workers: tuple[int, int] = (1, 2), reps: int = 2, items: int = 2000,
                    batch_size: int = 32, seed: int = 0) -> list[dict]:
    """Per variant (VARIANTS): items/s at workers[0] and workers[1] (alternated), the median speed-up,
    and the bytes one item moves between processes."""
    lo, hi = workers
    rows = []
    stores_maps = MapStorage.of(DatasetMetadata(root).manifest).stores_maps   # the records only: no shard opened
    for kind, source, options in VARIANTS:
        if source == "stored" and not stores_maps:
            continue   # a version without maps has no EXR to decode
        rates: dict[int, list[float]] = {lo: [], hi: []}
        for rep in range(reps):
            for w in (lo, hi):
                rates[w].append(_epoch_rate(root, w, source, items, batch_size, seed + rep, options))
        ratios = [b / a for a, b in zip(rates[lo], rates[hi])]
        dataset = TactileFrameDataset(root, options=ItemOptions(maps_from=source, **options))
        rows.append({"item": kind, "maps_from": source, "ipc_bytes_per_item": ipc_bytes(dataset[0]),
                     "items": min(items, len(dataset)), "batch_size": batch_size,
                     "workers_lo": lo, "workers_hi": hi, "reps": reps,
                     "items_per_s_lo": float(np.median(rates[lo])), "items_per_s_hi": float(np.median(rates[hi])),
                     "scaling": float(np.median(ratios)), "scaling_reps": ratios})
    return rows
