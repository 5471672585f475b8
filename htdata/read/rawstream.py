"""Read the raw glove rows a format-3 dataset stores: the full-rate stream, and maps rendered from raw.

- `MapServing`: where the loaders take maps from (`maps_from` = "best" |
  "stored" | "raw"; whether a version stores maps at all is
  htdata.format.mapstorage.MapStorage).

- `episode_stream(reader, episode, hand)`: every glove row the recording
  held, in time order, deduplicated by source row (a row paired with two
  frames is stored twice), with timestamps and source row numbers; what a
  100 Hz glove recorded between 30 Hz frames is all there.
- `RawMapRenderer`: the (224,224) map of a sample rendered from its paired
  raw row under the episode's recorded calibration (htdata.glove.calibration) and
  the dataset's raster mode, instead of decoding the stored EXR. In nearest
  mode this is a gather of exact float32 values; the stored map holds the
  same values rounded by the map codec (half float: <= 2.4e-4). `make bench`
  compares the two paths (frames/s and max difference).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError, DatasetError
from htdata.format.mapstorage import EXACT_RASTER, MapStorage
from htdata.format.table import JSON_MEMBER, MANIFEST_FILE, SEGMENTS_DIR, decode_member, raw_member
from htdata.format.tactilecodec import check_served_maps
from htdata.glove.calibration import episode_normaliser, refuse_mismatched
from htdata.glove.layouts import load_layout
from htdata.glove.rasterise import Rasteriser
from htdata.store import storage
from htdata.store.confine import inside
from htdata.store.versions import version_manifest_file


def check_records(reader) -> None:
    """Refuse (RecordMismatch, one line naming the file and record) a version whose calibration ids or
    calibration_fit digests do not match their content: every map rendered here, and every map
    `htdata renormalise` writes, would follow the edited record (htdata.glove.calibration.record_errors).

    Args:
        reader: the DatasetReader of the version.
    """
    refuse_mismatched(reader.manifest.get("calibrations", {}), reader.episodes,
                      storage.join(reader.root, MANIFEST_FILE if reader.version is None
                                   else version_manifest_file(reader.version)),
                      storage.join(reader.root, reader.manifest.get("episodes_file", SEGMENTS_DIR)),
                      reader.manifest.get("record_digests", ()))


# `reader` below is a htdata.read.reader.DatasetReader, not imported: the reader renders the maps of a
# version that does not store them with RawMapRenderer, so it imports this module.


@dataclass
class RawStream:
    """One hand's glove rows of one episode, full rate, in time order.

    Args:
        t_ns: (M,) int64 recorded glove timestamps.
        rows: (M,H,W) the rows as read, in the source dtype.
        source_row: (M,) int64 row numbers in the recording.
    """
    t_ns: np.ndarray
    rows: np.ndarray
    source_row: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ns.size)


def episode_stream(reader, episode: str | int, hand: str) -> RawStream:
    """Every stored raw row of `hand` in `episode`, in time order, each source row once.

    Args:
        reader: the DatasetReader of the version.
        episode: the episode id or its position in episodes.jsonl.
        hand: "left" or "right".

    Raises:
        ArgumentError: naming the episode when its samples hold no raw rows
            (datasets of format < 3, or ingested with keep_raw = false).
    """
    first, n = reader.episode_range(episode)
    eid = reader.episodes[reader.episode_position(episode)]["episode_id"]
    times, rows, values = [], [], []
    for i in range(first, first + n):
        members = reader.sample(i, (JSON_MEMBER, raw_member(hand)))
        if raw_member(hand) not in members:
            continue   # an RGB-only sample holds no rows
        meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], f"{eid} frame {i - first}")
        arr = decode_member(raw_member(hand), members[raw_member(hand)], f"{eid} frame {i - first}")
        times += meta["raw_t_ns"][hand]
        rows += meta["raw_row"][hand]
        values.append(arr)
    if not values:
        raise ArgumentError(f"episode {eid!r}: no raw {hand} rows stored (format < 3, or keep_raw = false)")
    t, r, v = np.asarray(times, np.int64), np.asarray(rows, np.int64), np.concatenate(values)
    order = np.lexsort((r, t))
    t, r, v = t[order], r[order], v[order]
    keep = np.sort(np.unique(r, return_index=True)[1])   # each source row once, time order kept
    return RawStream(t_ns=t[keep], rows=v[keep], source_row=r[keep])


def _sample_named(members: dict[str, bytes], where: str) -> str:
    """`where`, naming the sample by its JSON member's key when `where` names a batch (an episode, a group)."""
    try:
        key = decode_member(JSON_MEMBER, members[JSON_MEMBER], where).get("key")
    except (KeyError, ValueError, AttributeError):
        return where
    return where if not key or str(key) in where else f"{where}: sample {key}"


def paired_row(members: dict[str, bytes], hand: str, where: str, grid: tuple[int, int] | None = None) -> np.ndarray:
    """The raw row paired with a sample's frame, from its members (raw_<hand>.npy, + json when needed).

    A single stored row is the paired one (no JSON decode); otherwise
    meta["raw_paired"][hand] names it.

    Args:
        members: the sample's members (raw_<hand>.npy, + the json member when it holds several rows).
        hand: "left" or "right".
        where: the sample, named by errors.
        grid: the layout's (H, W): raw rows of another shape are a DatasetError naming the sample and member.
    """
    rows = decode_member(raw_member(hand), members[raw_member(hand)], where)
    if rows.ndim != 3 or (grid is not None and tuple(rows.shape[1:]) != tuple(grid)):
        want = f"(R, {grid[0]}, {grid[1]})" if grid is not None else "(R, H, W)"
        raise DatasetError(f"{_sample_named(members, where)}.{raw_member(hand)}: raw rows shaped {rows.shape}, "
                           f"expected {want}")
    if rows.shape[0] == 1:
        return rows[0]
    meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], where)
    at = (meta.get("raw_paired") or {}).get(hand)
    if rows.ndim != 3 or at is None or not 0 <= at < rows.shape[0]:
        raise DatasetError(f"{where}: meta raw_paired names row {at!r} of raw rows shaped {rows.shape}")
    return rows[at]


MAPS_FROM = ("best", "stored", "raw")   # the loaders' `maps_from` (not the storage words: MapStorage)
MAP_SOURCE_WORDS = {"auto": "best"}      # the deprecated `map_source=` values -> maps_from (htdata._moved)


@dataclass(frozen=True)
class MapServing:
    """Where the loaders take a version's maps from: THE rule (`choose`), shared by the torch datasets and
    `htdata validate` (which checks that rendered and stored maps agree).

    Args:
        rendered: maps are rendered from the paired raw rows (else the stored EXR is decoded).
        raw_required: maps_from="raw": a sample without raw rows is an error, never decoded.
    """
    rendered: bool
    raw_required: bool

    @classmethod
    def choose(cls, manifest: dict, maps_from: str = "best", where: str = "") -> "MapServing":
        """How the loaders serve the maps of the version whose manifest is `manifest`.

        "best" (the default): rendered from raw rows when they render the stored maps exactly (format 3,
        nearest raster) or when the version stores no maps, else the stored EXR decoded; "stored": the
        stored EXR (an error on a version that stores no maps); "raw": always rendered, and a sample
        without raw rows is an error.

        Args:
            manifest: the version's manifest.
            maps_from: "best", "stored" or "raw" (MAPS_FROM).
            where: the dataset named by the errors.

        Raises:
            ArgumentError: `maps_from` is not one of MAPS_FROM, or is "stored" on a version without maps.
        """
        if maps_from not in MAPS_FROM:
            old = f" (the old map_source={maps_from!r} is {MAP_SOURCE_WORDS[maps_from]!r})" \
                if maps_from in MAP_SOURCE_WORDS else ""
            raise ArgumentError(f"maps_from must be one of {MAPS_FROM}, got {maps_from!r}{old}")
        raw_required = maps_from == "raw"
        if not MapStorage.of(manifest).stores_maps:
            if maps_from == "stored":
                raise ArgumentError(f"{where or 'dataset'}: maps_from='stored', but this version stores no tactile "
                                    "maps (ingested with [tactile] maps = \"raw\"); its maps are rendered from the "
                                    "raw rows: use maps_from='best' or 'raw'")
            return cls(rendered=True, raw_required=raw_required)
        if maps_from != "best":
            return cls(rendered=raw_required, raw_required=raw_required)
        return cls(rendered=(manifest["codec"]["tactile"].get("raster_mode") == EXACT_RASTER
                             and manifest.get("format_version", 1) >= 3), raw_required=False)


def paired_source_row(members: dict[str, bytes], hand: str, where: str) -> int:
    """The source row number of the raw row paired with a sample's frame (meta raw_row / raw_paired).

    Args:
        members: the sample's members (the json member is read).
        hand: "left" or "right".
        where: the sample, named by errors.
    """
    meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], where)
    rows = (meta.get("raw_row") or {}).get(hand)
    at = (meta.get("raw_paired") or {}).get(hand, 0)
    if not rows or not 0 <= at < len(rows):
        raise DatasetError(f"{where}: meta raw_row / raw_paired do not name the paired {hand} row")
    return int(rows[at])


def apply_paired(normaliser, members: dict[str, bytes], hand: str, where: str):
    """normaliser.apply on a sample's paired raw row (with its source row number when the baseline drifts).

    Args:
        normaliser: the episode hand's Normaliser (its recorded calibration).
        members: the sample's members (json + raw_<hand>.npy).
        hand: "left" or "right".
        where: the sample, named by errors.
    """
    return apply_paired_many(normaliser, [members], hand, where)


def apply_paired_many(normaliser, members_list: list[dict[str, bytes]], hand: str, where: str):
    """normaliser.apply on the paired raw rows of several samples of one episode hand, in one call.

    Args:
        normaliser: the episode hand's Normaliser (its recorded calibration).
        members_list: each sample's members (json + raw_<hand>.npy).
        hand: "left" or "right".
        where: the samples, named by errors.
    """
    rows = ([paired_source_row(m, hand, where) for m in members_list]
            if normaliser.cfg.knotted else None)
    grid = tuple(normaliser.grid)
    return normaliser.apply(np.stack([paired_row(m, hand, where, grid) for m in members_list]), rows=rows)


class RawMapRenderer:
    """Maps from the paired raw rows (see the module docstring); one normaliser per episode hand, cached.

    Args:
        reader: the DatasetReader of the version (its manifest's calibrations, layouts, raster mode).
    """

    def __init__(self, reader):
        self.reader = reader
        self.mode = reader.manifest["codec"]["tactile"].get("raster_mode", "nearest")
        self._layouts: dict = {}
        self._rasters: dict = {}
        self._normalisers: dict = {}

    def parts_for(self, episode: int, hand: str):
        """(Normaliser with the episode's calibration, Rasteriser of its layout) for one episode hand.

        Args:
            episode: the episode's position in episodes.jsonl.
            hand: "left" or "right".
        """
        key = (episode, hand)
        if key not in self._normalisers:
            ep = self.reader.episodes[episode]
            lid = ep["layouts"][hand]
            if lid not in self._layouts:
                entry = self.reader.manifest["layouts"][lid]
                self._layouts[lid] = load_layout(Path(inside(self.reader.root, entry["file"], f"layouts.{lid}.file")))
                self._rasters[lid] = Rasteriser(self._layouts[lid], mode=self.mode)
            self._normalisers[key] = (episode_normaliser(self.reader.manifest, ep, hand, self._layouts[lid]),
                                      self._rasters[lid])
        return self._normalisers[key]

    def render(self, episode: int, hand: str, members: dict[str, bytes], where: str = "sample") -> np.ndarray:
        """(224,224) float32 map of one sample, rendered from its paired raw row.

        Args:
            episode: the sample's episode position.
            hand: "left" or "right".
            members: the sample's members (json + raw_<hand>.npy).
            where: the sample, named by errors.
        """
        normaliser, raster = self.parts_for(episode, hand)
        values, _ = apply_paired(normaliser, members, hand, where)
        return check_served_maps(raster.render(values)[0], f"{where} ({hand})")

    def render_many(self, episode: int, hand: str, members_list: list[dict[str, bytes]], where: str = "sample"
                    ) -> np.ndarray:
        """(n,224,224) float32 maps of n samples of one episode hand: one normalise and one rasterise call.

        Args:
            episode: the samples' episode position.
            hand: "left" or "right".
            members_list: each sample's members (json + raw_<hand>.npy).
            where: the samples, named by errors.
        """
        normaliser, raster = self.parts_for(episode, hand)
        values, _ = apply_paired_many(normaliser, members_list, hand, where)
        return check_served_maps(raster.render(values), f"{where} ({hand})")

    def sample_map(self, index: int, hand: str) -> np.ndarray:
        """(224,224) float32 map of sample `index`, read and rendered (KeyError when it holds no raw rows).

        Args:
            index: the global sample index.
            hand: "left" or "right".
        """
        row, key, members = self.reader.read_sample(index, (JSON_MEMBER, raw_member(hand)))
        if raw_member(hand) not in members:
            raise KeyError(f"{self.reader.root}: {key} has no raw {hand} rows")
        return self.render(row.episode, hand, members, f"{self.reader.root}: {key}")
