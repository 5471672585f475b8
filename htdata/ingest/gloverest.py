"""The glove's own rest by default: an ingest pools it over its recordings of each raw-count glove (issue 43).

A raw-count layout with no `[normalise.<id>]` table gets the raw-count default, which reads each
cell's rest from its own recording (a low percentile per window). A grip held through a whole
short recording is then taken for rest. When the ingest holds at least MIN_RECORDINGS
recordings of that glove (layout), its rest comes from the glove instead: each recording's
per-cell rest is pooled into a reference (htdata.glove.restreference, the same arithmetic as
`htdata layouts rest`), written to the dataset's work folder, and the layout is normalised with
baseline = "shift" on it (each recording's common-mode shift, per shift window) and noise_k 5,
as if the pipeline had a `[normalise.<id>]` table naming that file. Every episode record carries
the reference it was normalised with (its calibration's offset), so the dataset needs nothing
outside itself.

An append reuses the reference the dataset's episodes of that glove were normalised with
(htdata.glove.pooledrest): old and new episodes share one rest, and an appended recording
never re-normalises what is committed. A dataset whose first ingest had too few recordings of a
glove keeps the per-recording default for it, appends included (an append never changes how
committed episodes were normalised), until `htdata renormalise` pools the glove's rest over the
raw rows the dataset stores.
Pooling reads at most POOL_MAX recordings per glove, spread over the episode ids.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.errors import EpisodeError
from htdata.format.table import WORK_DIR
from htdata.glove.layouts import Layout, load_layout
from htdata.glove.pooledrest import REST_FILE_PREFIX, GloveRest, reused_rest, spread, write_work_reference
from htdata.glove.restreference import MIN_RECORDINGS, pooled_reference, recording_rest
from htdata.source.adapters import get_adapter

ROW_CHUNK = 4096
REST_BYTES = 64 << 20     # raw rows read per recording for its rest, at most (float32)


def _defaulted_hands(pairs: list[tuple]) -> dict[str, tuple[Layout, list[tuple]]]:
    """layout id -> (layout, [(ref, source, hand)]) for every raw-count layout without a table among the pairs."""
    out: dict[str, tuple[Layout, list[tuple]]] = {}
    for ref, source in pairs:
        normalising = source.pipeline.normalise_settings()     # one per pipeline: each layout resolved once
        for hand, path in sorted(ref.layout_files.items()):
            layout = load_layout(path)
            if normalising.default_note(layout) is not None:
                out.setdefault(layout.layout_id, (layout, []))[1].append((ref, source, hand))
    return out


def _recording_rows(ref, source, hand: str, grid: tuple[int, int]) -> np.ndarray:
    """(T,H,W) the raw rows of one episode hand, in the glove's units, read through the source's adapter: every
    row, or at most REST_BYTES of them evenly spaced (a rest is a low percentile: a long recording's every
    row adds nothing, and must not cost its whole length in memory)."""
    adapter = get_adapter(source.pipeline.adapter.name)
    with adapter.open(ref, source.pipeline.adapter.params) as streams:
        n = len(streams.tactile_timestamps_ns[hand])
        if n == 0:
            raise EpisodeError(ref, None, f"{hand} hand has no glove rows")
        most = max(1, REST_BYTES // (4 * grid[0] * grid[1]))
        rows = np.arange(n) if n <= most else np.unique(np.linspace(0, n - 1, most).round().astype(np.int64))
        return np.concatenate([np.asarray(streams.read_tactile(hand, rows[a:a + ROW_CHUNK]), np.float32)
                               for a in range(0, len(rows), ROW_CHUNK)])


def _recording_rests(layout: Layout, chosen: list[tuple]) -> list[np.ndarray]:
    """Each chosen (ref, source, hand)'s per-cell rest. A recording that cannot be read, or whose rows do not fit
    the layout, is left out here: its own work unit fails it and names the file, as without pooling."""
    rests = []
    for ref, source, hand in chosen:
        try:
            rows = _recording_rows(ref, source, hand, tuple(layout.grid))
        except (EpisodeError, OSError, ValueError):
            continue
        if rows.shape[1:] == tuple(layout.grid):
            rests.append(recording_rest(rows, layout.value["convention"]))
    return rests


def _in_dataset(parent, layout_id: str) -> bool:
    """The parent version holds episodes of the layout (normalised without a pooled rest, when it has none)."""
    return parent is not None and any(layout_id in (ep.get("layouts") or {}).values() for ep in parent.episodes)


def pool_glove_rests(pairs: list[tuple], out: Path, parent, progress=None) -> dict[str, GloveRest]:
    """The glove rest of every raw-count layout without a table among the (ref, source) pairs: reused from the
    parent's records, else pooled over the pairs' recordings when there are at least MIN_RECORDINGS of it.
    Layouts with fewer keep the raw-count default (they are not in the result)."""
    found: dict[str, GloveRest] = {}
    for layout_id, (layout, hands) in sorted(_defaulted_hands(pairs).items()):
        had = reused_rest(out, parent, layout)
        if had is not None:
            found[layout_id] = had
            continue
        if len(hands) < MIN_RECORDINGS or _in_dataset(parent, layout_id):
            continue    # too few to pool; or committed episodes keep their rest (renormalise pools over them)
        chosen = spread(sorted(hands, key=lambda x: (x[0].episode_id, x[2])))
        if progress is not None:
            progress(f"the glove rest of {layout_id}: pooling {len(chosen)} of its {len(hands)} recordings")
        rests = _recording_rests(layout, chosen)
        if len(rests) < MIN_RECORDINGS:
            continue
        found[layout_id] = GloveRest(layout_id, write_work_reference(out, layout_id, pooled_reference(rests)),
                                     len(rests))
    return found


def with_glove_rests(sources: list, rests: dict[str, GloveRest], pairs: list[tuple]) -> list:
    """The sources, each pipeline given a `[normalise.<id>]` table (baseline "shift" on the reference) for the
    pooled layouts its recordings use."""
    uses: dict[int, set[str]] = {}
    for ref, source in pairs:
        uses.setdefault(id(source), set()).update(load_layout(p).layout_id for p in ref.layout_files.values())
    out = []
    for s in sources:
        mine = {lid: r.path for lid, r in rests.items()          # a pipeline with its own table keeps it
                if lid in uses.get(id(s), set()) and lid not in s.pipeline.normalise}
        out.append(s if not mine else type(s)(pipeline=s.pipeline.with_glove_rests(mine), root=s.root))
    return out


def rest_notes(sources: list, rests: dict[str, GloveRest]) -> list[str]:
    """One note per pooled glove rest, naming the pipelines normalised with it."""
    return [r.note(sorted({s.pipeline.name for s in sources if lid in s.pipeline.normalise
                           and s.pipeline.normalise[lid].taxel_calibration == str(r.path)}))
            for lid, r in rests.items()]


def identity_settings(pipeline) -> dict:
    """`pipeline.to_dict()` with each pooled rest's file named by its content alone: the work folder moves
    with the dataset, so its path is no part of an episode's input fingerprint (an append to a moved
    dataset reuses its episodes); the name carries the layout id and the reference's sha256."""
    d = pipeline.to_dict()
    for table in d.get("normalise", {}).values():
        path = Path(table["taxel_calibration"]) if isinstance(table, dict) and table.get("taxel_calibration") else None
        if path is not None and path.parent.name == WORK_DIR and path.name.startswith(REST_FILE_PREFIX):
            table["taxel_calibration"] = path.name
    return d
