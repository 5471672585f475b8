"""Maps as the loaders serve them: rendered from the raw rows when they are, and equal to the stored maps.

The torch datasets' default (`maps_from="best"`, htdata/read/rawstream.py
`MapServing`) renders a version's maps from its stored raw rows
under the recorded calibration; the codec rule, the content checks and
`htdata renormalise` reason about the stored EXR maps. This check keeps the
two one truth: for the decoded samples (all with --deep, the seeded fraction
otherwise), every hand's map rendered as the loaders render it must equal
its stored map within the stored pixel type's rounding (half: half a unit in
the last place of the stored value; float: 1e-6). A calibration record that
no longer matches the maps, or maps written from other rows, fail here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from htdata.format.mapstorage import MapStorage
from htdata.format.table import HANDS, JSON_MEMBER, decode_member, raw_member, tactile_member
from htdata.read.rawstream import MapServing, RawMapRenderer
from htdata.read.reader import DatasetReader
from htdata.validate.content import check_map_values
from htdata.validate.geometry import CoverageGeometry
from htdata.validate.report import Check, Recorder

FLOAT_TOLERANCE = 1e-6
SERVED_FRACTION = 0.1


@dataclass
class RenderedCheck:
    """For a version without stored maps: which samples' maps to render and check, and where results go."""
    rows: np.ndarray                                 # (N,) bool: the samples whose content is decoded
    geometry: dict[str, CoverageGeometry]            # hand_key -> coverage geometry (validate.geometry)
    sensor: dict = field(default_factory=dict)       # the sensor accumulator (validate.sensors.accumulate)


def _check_rendered(reader: DatasetReader, rendered: RenderedCheck, check: Check, batch: int) -> None:
    """Render the maps of `rendered.rows` (batched per episode hand) and check their values."""
    rec, renderer = Recorder(), RawMapRenderer(reader)
    pending: dict[tuple[int, str], list[tuple[str, dict, int]]] = {}

    def flush(episode: int, hand: str, group: list) -> None:
        eid = reader.episodes[episode]["episode_id"]
        try:
            maps = renderer.render_many(episode, hand, [m for _, m, _ in group], group[0][0])
        except (ValueError, KeyError) as exc:
            for key, _, _ in group:
                rec.fail("served_map", f"{key} ({hand}): map from raw rows not rendered: {exc}", sample=key, hand=hand)
            return
        for (key, _, frame), tmap in zip(group, maps):
            rec.checked["served_maps_rendered"] += 1
            check_map_values(rendered.geometry, rec, f"{key} ({hand}, rendered from raw rows)",
                             {"key": key, "episode": eid, "frame": frame}, hand,
                             tmap.astype(np.float32, copy=False), rendered.sensor)

    for i in np.flatnonzero(rendered.rows):
        row, key, members = reader.read_sample(int(i), (JSON_MEMBER, *(raw_member(h) for h in HANDS)))
        for hand in HANDS:
            if raw_member(hand) in members:
                group = pending.setdefault((row.episode, hand), [])
                group.append((key, members, row.frame))
                if len(group) >= batch:
                    flush(row.episode, hand, pending.pop((row.episode, hand)))
    for (episode, hand), group in pending.items():
        flush(episode, hand, group)
    check.merge(rec.to_dict())


def allowed_error(stored: np.ndarray, pixel_type: str) -> np.ndarray | float:
    """Per pixel, how far a served value may be from the stored one: the stored pixel type's rounding."""
    if pixel_type == "half":
        return np.spacing(np.abs(stored).astype(np.float16)).astype(np.float32) / 2 + FLOAT_TOLERANCE
    return FLOAT_TOLERANCE


def served_rows(decoded: np.ndarray, episodes: np.ndarray, seed: int) -> np.ndarray:
    """Mask of the samples checked: each episode's first decoded one and a seeded share of the others."""
    chosen = decoded & (np.random.default_rng(seed).random(len(decoded)) < SERVED_FRACTION)
    positions = np.flatnonzero(decoded)
    _, first = np.unique(episodes[positions], return_index=True)
    chosen[positions[first]] = True
    return chosen


def check_served_maps(root, version: int | None, rows: np.ndarray, check: Check, batch: int = 64,
                      rendered: RenderedCheck | None = None) -> None:
    """Compare served and stored maps for sample positions `rows`; failures go to `check` ("served_map").

    Samples are read once each (json, maps and raw rows of both hands) and rendered in batches per
    episode hand, one normalise and one rasterise call per batch. A version that stores no maps has
    nothing to compare: its maps exist only as served, so `rendered` checks them as the content check
    checks stored ones (finite, in [0,1], zero outside coverage, the sensor accumulator).
    """
    reader = DatasetReader(root, version=version)
    if not MapStorage.of(reader.manifest).stores_maps:
        if rendered is not None:
            _check_rendered(reader, rendered, check, batch)
        return
    if not MapServing.choose(reader.manifest).rendered:
        check.checked["served_maps_stored"] += 1    # the loaders decode the stored maps: one truth already
        return
    renderer = RawMapRenderer(reader)
    pixel_type = reader.manifest["codec"]["tactile"].get("pixel_type", "half")
    suffixes = (JSON_MEMBER, *(tactile_member(h) for h in HANDS), *(raw_member(h) for h in HANDS))
    pending: dict[tuple[int, str], list[tuple[str, dict]]] = {}
    for i in np.flatnonzero(rows):
        row, key, members = reader.read_sample(int(i), suffixes)
        for hand in HANDS:
            if tactile_member(hand) in members and raw_member(hand) in members:
                group = pending.setdefault((row.episode, hand), [])
                group.append((key, members))
                if len(group) >= batch:
                    _compare(renderer, row.episode, hand, pending.pop((row.episode, hand)), pixel_type, check)
    for (episode, hand), group in pending.items():
        _compare(renderer, episode, hand, group, pixel_type, check)


def _compare(renderer: RawMapRenderer, episode: int, hand: str, group: list[tuple[str, dict]], pixel_type: str,
             check: Check) -> None:
    """Render one batch of an episode hand's samples and compare each with its stored map."""
    try:
        served = renderer.render_many(episode, hand, [m for _, m in group], group[0][0])
    except (ValueError, KeyError) as exc:
        for key, _ in group:
            check.fail("served_map", f"{key} ({hand}): map from raw rows not rendered: {exc}", sample=key, hand=hand)
        return
    for (key, members), one in zip(group, served):
        try:
            stored = decode_member(tactile_member(hand), members[tactile_member(hand)], key)
        except ValueError as exc:
            check.fail("served_map", f"{key} ({hand}): stored map does not decode: {exc}", sample=key, hand=hand)
            continue
        check.checked["served_maps"] += 1
        err = np.abs(one.astype(np.float32) - stored.astype(np.float32))
        over = err > allowed_error(stored, pixel_type)
        if over.any():
            check.fail("served_map", f"{key} ({hand}): the map the loaders render from raw rows differs from the "
                       f"stored map at {int(over.sum())} pixels (max {float(err.max()):.3g}): the calibration "
                       f"record and the stored maps disagree (`htdata renormalise` remakes both)",
                       sample=key, hand=hand, found=float(err.max()))
