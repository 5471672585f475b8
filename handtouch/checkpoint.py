"""Stage checkpoints: written atomically, read back with their RNG states (a resumed stage continues exactly)."""

from __future__ import annotations

import io
import random
from pathlib import Path

import numpy as np
import torch

from htdata.errors import ArgumentError
from htdata.fileio import write_bytes_atomic

CHECKPOINT_FORMAT = 1        # the "format" field of every stage checkpoint


# ---- checkpoints ---------------------------------------------------------------------
def rng_state() -> dict:
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"torch": torch.get_rng_state(), "numpy": [name, torch.from_numpy(keys.copy()), pos, has_gauss, cached],
            "python": random.getstate()}


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    name, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((name, keys.numpy(), pos, has_gauss, cached))
    random.setstate(state["python"])


def _to_tuple(obj):
    return tuple(_to_tuple(x) for x in obj) if isinstance(obj, list) else obj


def save_checkpoint(path: Path, payload: dict) -> None:
    """Atomic: a crash leaves the old checkpoint or the new one, never half of one."""
    buf = io.BytesIO()
    torch.save(payload, buf)
    write_bytes_atomic(path, buf.getbuffer())


def read_checkpoint(path: Path) -> dict:
    blob = torch.load(path, map_location="cpu", weights_only=True)
    if blob.get("format") != CHECKPOINT_FORMAT:
        raise ArgumentError(f"{path}: not a HandTouch checkpoint (format {blob.get('format')!r})")
    blob["rng"]["python"] = _to_tuple(blob["rng"]["python"])
    return blob
