"""The glove's own rest by default: an ingest pools it over its recordings of each raw-count glove (issue 43).

A raw-count layout with no `[normalise.<id>]` table gets the raw-count default, which reads each
cell's rest from its own recording (a low percentile per window). A grip held through a whole
short recording is then taken for rest. When the ingest holds at least MIN_RECORDINGS
recordings of that glove (layout), its rest comes from the glove instead: each recording's
per-cell rest is pooled into a reference (htdata.glove.restreference, the same arithmetic as
`htdata layouts rest`), written to DATASET/.work/, and the layout is normalised with
baseline = "shift" on it (each recording's common-mode shift, per shift window) and noise_k 5,
as if the pipeline had a `[normalise.<id>]` table naming that file. Every episode record carries
the reference it was normalised with (its calibration's offset), so the dataset needs nothing
outside itself.

An append reuses the reference the dataset's episodes of that glove were normalised with
(restored from their records): old and new episodes share one rest, and an appended recording
never re-normalises what is committed. A dataset whose first ingest had too few recordings of a
glove keeps the per-recording default for it until an ingest that holds enough of them (its
episodes re-ingested from their recordings, or `htdata renormalise` with a pipeline naming a
`layouts rest` file). Pooling reads at most POOL_MAX recordings per glove (spread over the
episode ids): the reference is a median, and more recordings would only cost the driver time.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import DatasetError, EpisodeError
from htdata.fileio import write_bytes_atomic
from htdata.format.table import WORK_DIR
from htdata.glove.calibration import episode_normaliser
from htdata.glove.layouts import Layout, load_layout
from htdata.glove.normalise import RAW_COUNT_DEFAULTS
from htdata.glove.restreference import MIN_RECORDINGS, pooled_reference, recording_rest, rest_reference_bytes
from htdata.source.adapters import get_adapter

POOL_MAX = 32
ROW_CHUNK = 4096


@dataclass(frozen=True)
class GloveRest:
    """One glove's pooled rest: the layout, the reference file in the work folder, where it came from."""
    layout_id: str
    path: Path
    recordings: int          # recordings pooled now (0: reused from the dataset)
    reused_from: str = ""    # the parent episode whose record carried it

    def note(self, pipelines: list[str]) -> str:
        origin = (f"reused from the dataset (episode {self.reused_from!r}'s record)" if self.reused_from else
                  f"pooled over {self.recordings} recordings of this ingest")
        return (f"layout {self.layout_id} holds raw counts and pipeline {', '.join(map(repr, pipelines))} has no "
                f"[normalise.{self.layout_id}] table: its rest is the glove's own, {origin} (each cell's rest = "
                f"the median over recordings of its 10th percentile), with each recording's common-mode shift "
                f"(baseline = \"shift\", noise_k = {RAW_COUNT_DEFAULTS['noise_k']:g}); docs/INGEST.md \"The "
                f"glove's own rest\"")


def _defaulted_hands(pairs: list[tuple]) -> dict[str, tuple[Layout, list[tuple]]]:
    """layout id -> (layout, [(ref, source, hand)]) for every raw-count layout without a table among the pairs."""
    out: dict[str, tuple[Layout, list[tuple]]] = {}
    settings: dict[int, object] = {}
    for ref, source in pairs:
        normalising = settings.setdefault(id(source), source.pipeline.normalise_settings())
        for hand, path in sorted(ref.layout_files.items()):
            layout = load_layout(path)
            if normalising.default_note(layout) is not None:
                out.setdefault(layout.layout_id, (layout, []))[1].append((ref, source, hand))
    return out


def _spread(items: list, most: int) -> list:
    """At most `most` of `items`, evenly spaced (first and last kept)."""
    if len(items) <= most:
        return items
    return [items[int(round(i))] for i in np.linspace(0, len(items) - 1, most)]


def _recording_rows(ref, source, hand: str) -> np.ndarray:
    """(T,H,W) every raw row of one episode hand, in the glove's units, read through the source's adapter."""
    adapter = get_adapter(source.pipeline.adapter.name)
    with adapter.open(ref, source.pipeline.adapter.params) as streams:
        n = len(streams.tactile_timestamps_ns[hand])
        if n == 0:
            raise EpisodeError(ref, None, f"{hand} hand has no glove rows")
        return np.concatenate([np.asarray(streams.read_tactile(hand, np.arange(a, min(n, a + ROW_CHUNK))),
                                          np.float32) for a in range(0, n, ROW_CHUNK)])


def _parent_reference(parent, layout: Layout) -> tuple[np.ndarray, str] | None:
    """The rest reference the dataset's episodes of `layout` were normalised with (the first episode whose
    calibration has baseline "shift" on a reference), and that episode's id; None when none was."""
    if parent is None:
        return None
    cals = parent.manifest.get("calibrations", {})
    for ep in parent.episodes:
        for hand, lid in sorted((ep.get("layouts") or {}).items()):
            entry = cals.get((ep.get("calibration") or {}).get(hand), {})
            if lid == layout.layout_id and entry.get("baseline") == "shift" and entry.get("taxel_calibration_sha256"):
                try:
                    offset = episode_normaliser(parent.manifest, ep, hand, layout).offset
                except (DatasetError, ValueError) as exc:
                    raise DatasetError(f"{parent.root}: episode {ep['episode_id']!r} {hand} hand: its glove rest "
                                       f"cannot be restored for an append: {exc}") from exc
                return np.asarray(offset, np.float32), ep["episode_id"]
    return None


def _write(out: Path, layout_id: str, reference: np.ndarray) -> Path:
    """The reference as a taxel calibration file in the work folder, named by its content (a new reference is a new
    file: the episodes' input fingerprints see the change)."""
    data = rest_reference_bytes(reference)
    path = out / WORK_DIR / f"glove-rest-{layout_id}-{hashlib.sha256(data).hexdigest()[:12]}.npz"
    if not path.is_file():
        write_bytes_atomic(path, data)
    return path


def pool_glove_rests(pairs: list[tuple], out: Path, parent, progress=None) -> dict[str, GloveRest]:
    """The glove rest of every raw-count layout without a table among the (ref, source) pairs: reused from the
    parent's records, else pooled over the pairs' recordings when there are at least MIN_RECORDINGS of it.
    Layouts with fewer keep the raw-count default (they are not in the result)."""
    found: dict[str, GloveRest] = {}
    for layout_id, (layout, hands) in sorted(_defaulted_hands(pairs).items()):
        had = _parent_reference(parent, layout)
        if had is not None:
            found[layout_id] = GloveRest(layout_id, _write(out, layout_id, had[0]), 0, had[1])
            continue
        if len(hands) < MIN_RECORDINGS:
            continue
        chosen = _spread(sorted(hands, key=lambda x: (x[0].episode_id, x[2])), POOL_MAX)
        if progress is not None:
            progress(f"the glove rest of {layout_id}: pooling {len(chosen)} of its {len(hands)} recordings")
        rests = []
        for ref, source, hand in chosen:
            rows = _recording_rows(ref, source, hand)
            if rows.shape[1:] != tuple(layout.grid):
                raise EpisodeError(ref, None, f"{hand} rows are {rows.shape[1]}x{rows.shape[2]}, layout "
                                              f"{layout_id} is {layout.grid[0]}x{layout.grid[1]}")
            rests.append(recording_rest(rows, layout.value["convention"]))
        found[layout_id] = GloveRest(layout_id, _write(out, layout_id, pooled_reference(rests)), len(rests))
    return found


def with_glove_rests(sources: list, rests: dict[str, GloveRest], pairs: list[tuple]) -> list:
    """The sources, each pipeline given a `[normalise.<id>]` table (baseline "shift" on the reference) for the
    pooled layouts its recordings use."""
    uses: dict[int, set[str]] = {}
    for ref, source in pairs:
        uses.setdefault(id(source), set()).update(load_layout(p).layout_id for p in ref.layout_files.values())
    out = []
    for s in sources:
        mine = {lid: r.path for lid, r in rests.items() if lid in uses.get(id(s), set())}
        out.append(s if not mine else type(s)(pipeline=s.pipeline.with_glove_rests(mine), root=s.root))
    return out
