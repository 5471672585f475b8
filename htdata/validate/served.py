"""Maps as the loaders serve them: rendered from the raw rows when they are, and equal to the stored maps.

The torch datasets' default (`map_source="auto"`, htdata/read/rawstream.py
`serves_maps_from_raw`) renders a version's maps from its stored raw rows
under the recorded calibration; the codec rule, the content checks and
`htdata renormalise` reason about the stored EXR maps. This check keeps the
two one truth: for the decoded samples (all with --deep, the seeded fraction
otherwise), every hand's map rendered as the loaders render it must equal
its stored map within the stored pixel type's rounding (half: half a unit in
the last place of the stored value; float: 1e-6). A calibration record that
no longer matches the maps, or maps written from other rows, fail here.
"""

from __future__ import annotations

import numpy as np

from htdata.format.table import HANDS, JSON_MEMBER, decode_member, raw_member, tactile_member
from htdata.read.rawstream import RawMapRenderer, serves_maps_from_raw
from htdata.read.reader import DatasetReader
from htdata.validate.report import Check

FLOAT_TOLERANCE = 1e-6


def allowed_error(stored: np.ndarray, pixel_type: str) -> np.ndarray | float:
    """Per pixel, how far a served value may be from the stored one: the stored pixel type's rounding."""
    if pixel_type == "half":
        return np.spacing(np.abs(stored).astype(np.float16)).astype(np.float32) / 2 + FLOAT_TOLERANCE
    return FLOAT_TOLERANCE


def check_served_maps(root, version: int | None, rows: np.ndarray, check: Check) -> None:
    """Compare served and stored maps for sample positions `rows`; failures go to `check` ("served_map")."""
    reader = DatasetReader(root, version=version)
    if not serves_maps_from_raw(reader.manifest):
        check.checked["served_maps_stored"] += 1    # the loaders decode the stored maps: one truth already
        return
    renderer = RawMapRenderer(reader)
    pixel_type = reader.manifest["codec"]["tactile"].get("pixel_type", "half")
    for i in np.flatnonzero(rows):
        for hand in HANDS:
            suffixes = (JSON_MEMBER, tactile_member(hand), raw_member(hand))
            row, key, members = reader.read_sample(int(i), suffixes)
            if tactile_member(hand) not in members or raw_member(hand) not in members:
                continue
            where = f"{key} ({hand})"
            try:
                stored = decode_member(tactile_member(hand), members[tactile_member(hand)], key)
                served = renderer.render(row.episode, hand, members, key)
            except (ValueError, KeyError) as exc:
                check.fail("served_map", f"{where}: map from raw rows not rendered: {exc}", sample=key, hand=hand)
                continue
            check.checked["served_maps"] += 1
            err = np.abs(served.astype(np.float32) - stored.astype(np.float32))
            over = err > allowed_error(stored, pixel_type)
            if over.any():
                check.fail("served_map", f"{where}: the map the loaders render from raw rows differs from the "
                           f"stored map at {int(over.sum())} pixels (max {float(err.max()):.3g}): the calibration "
                           f"record and the stored maps disagree (`htdata renormalise` remakes both)",
                           sample=key, hand=hand, found=float(err.max()))
