"""Whether a version's samples store their tactile maps, or only the raw rows every htdata reader renders them from.

The pipeline's `[tactile] maps` picks it at ingest and the manifest records it
beside the raster mode, in codec.tactile.maps:
- "stored": each hand frame has a `tactile_<hand>.exr` member (what a plain
  tar / webdataset reader that is not htdata sees);
- "raw": no map members; the sample keeps `raw_<hand>.npy` and the json
  member's raw_row / raw_paired, and htdata's readers render the map from the
  paired row under the episode's calibration (htdata.read.rawstream), exact in
  nearest raster mode. Saves the map bytes (~30% of a sample).
A version without the record (every dataset written before the setting) stores its maps; so does a new
dataset unless its pipeline says `maps = "raw"` (`resolve_map_storage`).

A hand is present in a sample when its map or its raw rows are stored: raw
rows ride only in samples with a map (htdata.ingest.fullrate), so this one
test reads both kinds of dataset from index.npy alone (`hand_present`).
"""

from __future__ import annotations

import numpy as np

from htdata.format.table import SIZE_FIELDS, raw_member, tactile_member

MAP_STORAGE = ("stored", "raw")   # manifest codec.tactile.maps
MAP_SETTINGS = ("auto",) + MAP_STORAGE   # [tactile] maps in a pipeline
UNRECORDED = "stored"             # what a version without the record holds (written before the setting)


def resolve_map_storage(setting: str, parent_manifest: dict | None) -> str:
    """The storage an ingest uses for `[tactile] maps = setting`.

    "auto" (the default): an append keeps the parent version's choice (one kind per version); a new
    dataset stores its maps: the published format is 224x224 maps a reader without htdata opens with
    tar + OpenEXR (tests/format/test_maps_thirdparty.py). "raw" saves ~25% of the bytes, so it stays an
    explicit opt-in for datasets read only through htdata. "stored" / "raw" are taken as given (an
    append whose parent holds the other kind is refused by the commit's compatibility check, naming
    the setting).
    """
    if setting != "auto":
        return setting
    if parent_manifest is not None:
        return map_storage(parent_manifest)
    return "stored"


def map_storage(manifest: dict) -> str:
    """The version's choice ("stored" when not recorded); an unknown value is an error naming it."""
    value = manifest.get("codec", {}).get("tactile", {}).get("maps", UNRECORDED)
    if value not in MAP_STORAGE:
        raise ValueError(f"manifest codec.tactile.maps = {value!r}: not one of {MAP_STORAGE} "
                         f"(written by a newer htdata?)")
    return value


def maps_stored(manifest: dict) -> bool:
    return map_storage(manifest) == "stored"


def with_map_record(codec: dict) -> dict:
    """A copy of a manifest "codec" block with codec.tactile.maps filled in (absent = "stored"), to compare two."""
    tactile = {**codec.get("tactile", {})}
    tactile.setdefault("maps", UNRECORDED)
    return {**codec, "tactile": tactile}


def hand_present(rows: np.ndarray, hand: str) -> np.ndarray:
    """(N,) bool from index rows: the sample holds `hand`'s map, stored or to be rendered from its raw rows."""
    return (rows[SIZE_FIELDS[tactile_member(hand)]] > 0) | (rows[SIZE_FIELDS[raw_member(hand)]] > 0)


def has_hand(members: dict, hand: str) -> bool:
    """The same test on a sample's members (those read: ask for the tactile and raw members)."""
    return tactile_member(hand) in members or raw_member(hand) in members


def map_member(manifest: dict, hand: str) -> str:
    """The member whose presence says a sample holds `hand`'s map: its EXR when stored, else its raw rows."""
    return tactile_member(hand) if maps_stored(manifest) else raw_member(hand)
