"""Raw activity of recordings, for `htdata layouts check --against` and `htdata layouts suggest`.

A RECORDING is either a source folder read by a pipeline's adapter (default
the native format: a recording folder or a folder of them; every episode
found is scanned) or a `.npy` file of raw rows (T,H,W) of one hand. Rows are
read in chunks in the glove's raw units and folded into a
`htdata.glove.activity.CellActivity` per episode and hand; nothing is normalised.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, EpisodeError
from htdata.glove.activity import CellActivity
from htdata.ingest.pipeline import PipelineConfig, load_pipeline
from htdata.source.adapters import get_adapter, nothing_found
from htdata.source.adapters.streamchecks import ANY_GRID

CHUNK_ROWS = 512


@dataclass
class ScannedHand:
    """One episode's hand: where it came from, the layout it names (if any), its activity."""

    recording: str
    episode_id: str
    hand: str
    layout: str | None
    activity: CellActivity
    integral: bool      # every finite value is a whole number (raw counts)
    rows: np.ndarray | None = None   # every raw row (T,H,W) float32, when scanned with keep_rows


def _fold(activity: CellActivity, rows: np.ndarray, integral: bool) -> bool:
    activity.add(rows)
    x = np.asarray(rows, np.float32)
    finite = x[np.isfinite(x)]
    return integral and bool(np.all(finite == np.round(finite)))


def _scan_npy(path: Path, hand: str | None, keep_rows: bool = False) -> list[ScannedHand]:
    if hand is None:
        raise ArgumentError(f"{path}: a .npy recording holds one hand's rows: say which (--hand left|right)")
    try:
        rows = np.load(path, mmap_mode="r")
    except (OSError, ValueError) as e:
        raise ArgumentError(f"{path}: not a readable .npy array: {e}") from None
    if rows.ndim != 3 or not (np.issubdtype(rows.dtype, np.number)):
        raise ArgumentError(f"{path}: expected raw rows (T,H,W) of numbers, got {rows.dtype} {rows.shape}")
    act, integral = CellActivity(rows.shape[1:]), True
    for a in range(0, len(rows), CHUNK_ROWS):
        integral = _fold(act, rows[a:a + CHUNK_ROWS], integral)
    return [ScannedHand(str(path), path.stem, hand, None, act, integral,
                        np.asarray(rows, np.float32) if keep_rows else None)]


def _scan_source(path: Path, pipeline, hand: str | None, layout_file: str | None,
                 keep_rows: bool = False) -> list[ScannedHand]:
    import dataclasses


    adapter = get_adapter(pipeline.adapter.name)
    params = pipeline.adapter.params
    refs, bad = adapter.discover_all(path, params)
    if bad:
        e = bad[0]
        raise ArgumentError(f"{e.file or path}: {e.message}")
    if not refs:
        raise ArgumentError(f"{nothing_found(pipeline.adapter.name, path)} (pipeline {pipeline.path or pipeline.name})")
    out = []
    for ref in refs:
        hands = [h for h in ref.hands if hand is None or h == hand]
        # The rows are read as the layout under check sees them (or, to suggest one, whatever their grid):
        # the layout the recording names need not exist yet.
        ref = dataclasses.replace(ref, layout_files={h: layout_file or ANY_GRID for h in ref.hands})
        try:
            with adapter.open(ref, params) as streams:
                for h in hands:
                    n = len(streams.tactile_timestamps_ns[h])
                    act, integral, kept = None, True, []
                    for a in range(0, n, CHUNK_ROWS):
                        rows = np.asarray(streams.read_tactile(h, np.arange(a, min(n, a + CHUNK_ROWS))))
                        act = act or CellActivity(rows.shape[1:])
                        integral = _fold(act, rows, integral)
                        if keep_rows:
                            kept.append(np.asarray(rows, np.float32))
                    if act is not None:
                        out.append(ScannedHand(ref.source_ref, ref.episode_id, h, ref.layouts.get(h), act, integral,
                                               np.concatenate(kept) if keep_rows else None))
        except EpisodeError as e:
            raise ArgumentError(f"{e.file or ref.source_ref} [{ref.episode_id}]: {e.message}") from None
    return out


def scan_recordings(paths: list[str | Path], pipeline="native", hand: str | None = None,
                    layout_file: str | None = None, keep_rows: bool = False) -> list[ScannedHand]:
    """Activity of every episode hand in `paths` (only `hand` when given); ValueError names the file.

    `layout_file`: the layout JSON the rows must fit (check --against); None reads any grid (suggest).
    `keep_rows`: also keep each hand's raw rows (`layouts rest` takes percentiles of them).
    """

    cfg = pipeline if isinstance(pipeline, PipelineConfig) else load_pipeline(pipeline)
    out: list[ScannedHand] = []
    for p in map(Path, paths):
        if not p.exists():
            raise ArgumentError(f"recording {p} does not exist")
        out += _scan_npy(p, hand, keep_rows) if p.suffix == ".npy" else _scan_source(p, cfg, hand, layout_file,
                                                                                    keep_rows)
    return out
