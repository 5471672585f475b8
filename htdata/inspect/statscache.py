"""Reading one entry of DATASET/stats/ (htdata stats' cache) no further than its shape.

The cache is a file in a dataset a stranger may have made: an entry is used only when it parses
and every field the readers walk has the type they expect (numeric arrays flat, region and
health records one level deep), else it is recomputed. A JSON Schema validator would take ~50
ms an entry on a raw-count glove's arrays; numpy's conversion checks an array in microseconds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

SCALAR = (int, float, str, bool, type(None))
ARRAYS = ("frame_contact", "frame_index", "frame_max", "hist", "raw_hist", "taxel_sum", "taxel_sumsq")
CELL_LISTS = ("unexercised_cells", "unmapped_moving_cells")


def read_entry(path: Path | None) -> dict | None:
    """The entry at `path`, or None when absent, unreadable, too deeply nested to parse, or not of the shape
    `well_formed` checks (a damaged entry is recomputed, and not rewritten: its name is taken)."""
    if path is None or not path.exists():
        return None
    try:
        entry = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    return entry if well_formed(entry) else None


def well_formed(entry) -> bool:
    """True when every field the stats readers walk has the type they expect."""
    if not isinstance(entry, dict) or not isinstance(entry.get("episode_id"), str):
        return False
    if not _count(entry.get("frames")) or not isinstance(entry.get("hands"), dict):
        return False
    if not isinstance(entry.get("nan_samples", []), list) or not _flat(entry.get("nan_samples", [])):
        return False
    return all(isinstance(h, dict) and _hand_ok(h) for h in entry["hands"].values())


def _hand_ok(h: dict) -> bool:
    if not isinstance(h.get("layout"), str) or not _count(h.get("frames")):
        return False
    for key, value in h.items():
        if key in ARRAYS:
            if not _numbers(value):
                return False
        elif key == "contact_rule":
            if not _record(value):
                return False
        elif key == "regions":
            if not isinstance(value, dict) or not all(_record(r) for r in value.values()):
                return False
        elif key == "health":
            if not _health_ok(value):
                return False
        elif not isinstance(value, SCALAR):
            return False
    return True


def _health_ok(health) -> bool:
    if not isinstance(health, dict):
        return False
    for key, value in health.items():
        if key == "counts":
            if not isinstance(value, dict) or not all(_count(v) for v in value.values()):
                return False
        elif key == "cells":
            if not isinstance(value, dict) or not all(_cells(v) for v in value.values()):
                return False
        elif key in CELL_LISTS:
            if not _cells(value):
                return False
        elif not isinstance(value, SCALAR):
            return False
    return True


def _count(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= 0


def _record(x) -> bool:
    return isinstance(x, dict) and all(isinstance(v, SCALAR) for v in x.values())


def _flat(values: list) -> bool:
    return all(isinstance(v, SCALAR) for v in values)


def _numbers(x) -> bool:
    """A flat list of finite-or-not numbers (no nesting, no strings): numpy converts it to a 1-D float array."""
    if not isinstance(x, list):
        return False
    try:
        return np.asarray(x, np.float64).ndim == 1
    except (TypeError, ValueError, OverflowError):
        return False


def _cells(x) -> bool:
    """A list of (row, col) pairs."""
    if not isinstance(x, list):
        return False
    if not x:
        return True
    try:
        a = np.asarray(x, np.int64)
    except (TypeError, ValueError, OverflowError):
        return False
    return a.ndim == 2 and a.shape[1] == 2
