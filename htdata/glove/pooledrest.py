"""A dataset's pooled glove rest: the reference its episodes of a glove were normalised with, and where a run keeps it.

An ingest (htdata/ingest/gloverest.py: pooled over the recordings it reads) and
`htdata renormalise` (htdata/curate/renormalise.py: over the raw rows the dataset
stores) give a raw-count layout without a `[normalise.<id>]` table the glove's own
rest (htdata.glove.restreference). Both first look for the one the dataset already
has: every episode record carries the reference it was normalised with (its
calibration's offset), so a later command reuses it and old and new episodes
share one rest. The run writes the reference into the dataset's work folder,
named by its content (a new reference is a new file and a new calibration id),
and normalises with the table `glove_rest_config` names.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import DatasetError
from htdata.fileio import write_bytes_atomic
from htdata.format.table import WORK_DIR
from htdata.glove.calibration import config_of, episode_normaliser
from htdata.glove.layouts import Layout
from htdata.glove.normaliseconfig import RAW_COUNT_DEFAULTS
from htdata.glove.restreference import rest_reference_bytes

REST_FILE_PREFIX = "glove-rest-"   # DATASET/.work/glove-rest-<layout>-<sha12>.npz
POOL_MAX = 32       # recordings pooled per glove at most: the reference is a median, more only cost time


@dataclass(frozen=True)
class GloveRest:
    """One glove's pooled rest: the layout, the reference file in the work folder, where it came from."""
    layout_id: str
    path: Path
    recordings: int          # recordings pooled now (0: reused from the dataset)
    reused_from: str = ""    # the episode whose record carried it
    pooled_over: str = "recordings of this ingest"

    def note(self, pipelines: list[str]) -> str:
        origin = (f"reused from the dataset (episode {self.reused_from!r}'s record)" if self.reused_from else
                  f"pooled over {self.recordings} {self.pooled_over}")
        return (f"layout {self.layout_id} holds raw counts and pipeline {', '.join(map(repr, pipelines))} has no "
                f"[normalise.{self.layout_id}] table: its rest is the glove's own, {origin} (each cell's rest = "
                f"the median over recordings of its 10th percentile), with each recording's common-mode shift "
                f"(baseline = \"shift\", noise_k = {RAW_COUNT_DEFAULTS['noise_k']:g}); docs/INGEST.md \"The "
                f"glove's own rest\"")


def spread(items: list, most: int = POOL_MAX) -> list:
    """At most `most` of `items`, evenly spaced (first and last kept)."""
    if len(items) <= most:
        return items
    return [items[int(round(i))] for i in np.linspace(0, len(items) - 1, most)]


def dataset_reference(snap, layout: Layout) -> tuple[np.ndarray, str] | None:
    """The rest reference the version's episodes of `layout` were normalised with (the first episode whose
    calibration has baseline "shift" on a reference) and that episode's id; None when none was."""
    if snap is None:
        return None
    # each calibration record read once (a dataset has few, and thousands of episodes name them)
    pooled = {cid for cid, entry in snap.manifest.get("calibrations", {}).items()
              if entry.get("layout") == layout.layout_id and config_of(entry).rest_from_glove}
    for ep in snap.episodes:
        for hand, lid in sorted((ep.get("layouts") or {}).items()):
            if lid == layout.layout_id and (ep.get("calibration") or {}).get(hand) in pooled:
                try:
                    offset = episode_normaliser(snap.manifest, ep, hand, layout).offset
                except (DatasetError, ValueError) as exc:
                    raise DatasetError(f"{snap.root}: episode {ep['episode_id']!r} {hand} hand: its glove rest "
                                       f"cannot be restored: {exc}") from exc
                return np.asarray(offset, np.float32), ep["episode_id"]
    return None


def write_work_reference(root: Path, layout_id: str, reference: np.ndarray) -> Path:
    """The reference as a taxel calibration file in the dataset's work folder, named by its content."""
    data = rest_reference_bytes(reference)
    path = Path(root) / WORK_DIR / f"{REST_FILE_PREFIX}{layout_id}-{hashlib.sha256(data).hexdigest()[:12]}.npz"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, data)
    return path


def reused_rest(root: Path, snap, layout: Layout) -> GloveRest | None:
    """The dataset's own reference for `layout`, written to the work folder (None: the dataset has none)."""
    had = dataset_reference(snap, layout)
    if had is None:
        return None
    return GloveRest(layout.layout_id, write_work_reference(root, layout.layout_id, had[0]), 0, had[1])
