"""Whether a version's samples store their tactile maps, or only the raw rows every htdata reader renders them from.

`MapStorage` is the one owner of that choice: its words, its rules and its records.
- STORED: each hand frame has a `tactile_<hand>.exr` member (what a plain tar /
  webdataset reader that is not htdata sees);
- RAW: no map members; the sample keeps `raw_<hand>.npy` and the json member's
  raw_row / raw_paired, and htdata's readers render the map from the paired row
  under the episode's calibration (htdata.read.rawstream), exact only in nearest
  raster mode. Saves the map bytes (~30% of a sample);
- AUTO: a pipeline setting only (`[tactile] maps`, the default), resolved per
  ingest (`resolved`): an append keeps its parent version's choice, a new
  dataset stores its maps.
Where it is written: the pipeline's `[tactile] maps` ("auto" | "stored" | "raw",
`parse`), the manifest's codec.tactile.maps ("stored" | "raw", `record`; a
version without it was written before the setting and stores its maps: `of`).
The loaders' own option (`maps_from`, htdata.read.rawstream) has words of its own.

A hand is present in a sample when its map or its raw rows are stored: raw
rows ride only in samples with a map (htdata.ingest.fullrate), so this one
test reads both kinds of dataset from index.npy alone (`hand_present`).
"""

from __future__ import annotations

import difflib
from enum import Enum

import numpy as np

from htdata.errors import ConfigError, DatasetError
from htdata.format.table import SIZE_FIELDS, raw_member, tactile_member

# The one raster mode whose maps the raw rows render exactly (a gather of the normalised values).
EXACT_RASTER = "nearest"


class MapStorage(Enum):
    """Maps stored or rendered from raw rows: a pipeline's setting, or a version's resolved choice."""

    AUTO = "auto"        # a setting only: the parent's choice on append, else STORED
    STORED = "stored"
    RAW = "raw"

    def __repr__(self) -> str:   # messages show the word a user writes
        return repr(self.value)

    def __str__(self) -> str:
        return self.value

    @classmethod
    def parse(cls, value, where: str = "pipeline") -> "MapStorage":
        """The storage a pipeline's `[tactile] maps = value` asks for.

        Args:
            value: the setting as written ("auto", "stored" or "raw"), or a MapStorage.
            where: the pipeline file (or `--set`) named by the error.

        Raises:
            ConfigError: one line naming `[tactile] maps` and the allowed values, for any other value.
        """
        if isinstance(value, cls):
            return value
        words = [m.value for m in cls]
        if value in words:
            return cls(value)
        near = difflib.get_close_matches(str(value), words, n=1, cutoff=0.6)
        raise ConfigError(f"{where}: [tactile] maps = {value!r}: must be one of "
                          f"{', '.join(map(repr, words))}" + (f"; did you mean {near[0]!r}?" if near else ""))

    @classmethod
    def from_codec(cls, codec: dict) -> "MapStorage":
        """A version's choice from its manifest "codec" block (codec.tactile.maps; absent: STORED).

        Raises:
            DatasetError: the record holds another value (written by a newer htdata?), naming it.
        """
        value = codec.get("tactile", {}).get("maps", cls.STORED.value)
        if value not in (cls.STORED.value, cls.RAW.value):
            raise DatasetError(f"manifest codec.tactile.maps = {value!r}: not one of "
                               f"{(cls.STORED.value, cls.RAW.value)} (written by a newer htdata?)")
        return cls(value)

    @classmethod
    def of(cls, manifest: dict) -> "MapStorage":
        """A version's choice from its manifest (see `from_codec`)."""
        return cls.from_codec(manifest.get("codec", {}))

    @classmethod
    def comparable_codec(cls, codec: dict) -> dict:
        """A copy of a manifest "codec" block with codec.tactile.maps filled in, to compare two versions' blocks."""
        return {**codec, "tactile": {**codec.get("tactile", {}), "maps": cls.from_codec(codec).record}}

    def resolved(self, parent_manifest: dict | None) -> "MapStorage":
        """The choice an ingest makes for this setting.

        AUTO (the default): an append keeps the parent version's choice (one kind per version); a new
        dataset stores its maps: the published format is 224x224 maps a reader without htdata opens with
        tar + OpenEXR (tests/format/test_maps_thirdparty.py). RAW saves ~25% of the bytes, so it stays an
        explicit opt-in for datasets read only through htdata. STORED / RAW are taken as given (an
        append whose parent holds the other kind is refused by the commit's compatibility check).

        Args:
            parent_manifest: the manifest of the version appended to, or None for a new dataset.
        """
        if self is not MapStorage.AUTO:
            return self
        return MapStorage.of(parent_manifest) if parent_manifest is not None else MapStorage.STORED

    def check_tactile(self, keep_raw: bool, raster_mode: str, where: str) -> None:
        """Refuse RAW where the readers could not render the maps the ingest would have stored.

        Args:
            keep_raw: `[tactile] keep_raw` (RAW renders from the stored raw rows: it needs them).
            raster_mode: `[tactile] raster_mode` (only EXACT_RASTER renders exactly).
            where: the pipeline file (or `--set`) named by the error.

        Raises:
            ConfigError: naming `[tactile] maps` and the setting that rules RAW out.
        """
        if self is not MapStorage.RAW:
            return
        if not keep_raw:
            raise ConfigError(f"{where}: [tactile] maps = \"raw\" needs keep_raw = true: readers render the maps "
                              f"from the stored raw rows, and keep_raw = false stores none")
        if raster_mode != EXACT_RASTER:
            raise ConfigError(f"{where}: [tactile] maps = \"raw\" needs raster_mode = \"{EXACT_RASTER}\" (got "
                              f"{raster_mode!r}): only a nearest raster renders from raw rows exactly what "
                              f"the ingest would have stored; keep maps = \"stored\" for {raster_mode}")

    def decided(self) -> "MapStorage":
        """This choice, refused while it is AUTO (an ingest resolves it before its units run or it commits)."""
        if self is MapStorage.AUTO:
            raise RuntimeError("[tactile] maps = 'auto' is not resolved: MapStorage.resolved(parent manifest) "
                               "decides it once per ingest, before units run")
        return self

    @property
    def stores_maps(self) -> bool:
        """Whether samples hold their maps as tactile_<hand>.exr members (else readers render them)."""
        return self.decided() is MapStorage.STORED

    @property
    def record(self) -> str:
        """What the manifest's codec.tactile.maps holds for this (resolved) choice."""
        return self.decided().value

    @property
    def pipeline_value(self) -> str | None:
        """What a pipeline's dict (`to_dict`, recorded in the manifest's sources and unit fingerprints) holds
        under [tactile] maps: only "raw" is written, so every pipeline written before the setting (and
        "stored" / "auto") keeps its dict, its episode settings and its unit fingerprints."""
        return self.value if self is MapStorage.RAW else None

    def map_member(self, hand: str) -> str:
        """The member whose presence says a sample holds `hand`'s map: its EXR when stored, else its raw rows."""
        return tactile_member(hand) if self.stores_maps else raw_member(hand)


def hand_present(rows: np.ndarray, hand: str) -> np.ndarray:
    """(N,) bool from index rows: the sample holds `hand`'s map, stored or to be rendered from its raw rows."""
    return (rows[SIZE_FIELDS[tactile_member(hand)]] > 0) | (rows[SIZE_FIELDS[raw_member(hand)]] > 0)


def has_hand(members: dict, hand: str) -> bool:
    """The same test on a sample's members (those read: ask for the tactile and raw members)."""
    return tactile_member(hand) in members or raw_member(hand) in members
