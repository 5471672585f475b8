"""Read the raw glove rows a format-3 dataset stores: the full-rate stream, and maps rendered from raw.

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

from htdata.errors import ArgumentError
from htdata.errors import DatasetError
from htdata.glove.calibration import episode_normaliser, refuse_mismatched
from htdata.store import storage
from htdata.store.versions import version_manifest_file
from htdata.format.mapstorage import maps_stored
from htdata.format.codec import check_finite_maps
from htdata.format.table import JSON_MEMBER, MANIFEST_FILE, decode_member, raw_member
from htdata.store.confine import inside
from htdata.glove.layouts import load_layout
from htdata.glove.rasterise import Rasteriser


def check_records(reader) -> None:
    """Refuse (RecordMismatch, one line naming the file and record) a version whose calibration ids or
    calibration_fit digests do not match their content: every map rendered here, and every map
    `htdata renormalise` writes, would follow the edited record (htdata.glove.calibration.record_errors)."""
    refuse_mismatched(reader.manifest.get("calibrations", {}), reader.episodes,
                      storage.join(reader.root, MANIFEST_FILE if reader.version is None
                                   else version_manifest_file(reader.version)),
                      storage.join(reader.root, reader.manifest.get("episodes_file", "episodes.jsonl")))


# `reader` below is a htdata.read.reader.DatasetReader, not imported: the reader renders the maps of a
# version that does not store them with RawMapRenderer, so it imports this module.


@dataclass
class RawStream:
    """One hand's glove rows of one episode, full rate: (M,) times, (M,H,W) rows in the source dtype, (M,) rows."""
    t_ns: np.ndarray
    rows: np.ndarray
    source_row: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ns.size)


def episode_stream(reader, episode: str | int, hand: str) -> RawStream:
    """Every stored raw row of `hand` in `episode`, in time order, each source row once.

    Raises ValueError naming the episode when its samples hold no raw rows
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


def paired_row(members: dict[str, bytes], hand: str, where: str) -> np.ndarray:
    """The raw row paired with a sample's frame, from its members (raw_<hand>.npy, + json when needed).

    A single stored row is the paired one (no JSON decode); otherwise
    meta["raw_paired"][hand] names it.
    """
    rows = decode_member(raw_member(hand), members[raw_member(hand)], where)
    if rows.ndim == 3 and rows.shape[0] == 1:
        return rows[0]
    meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], where)
    at = (meta.get("raw_paired") or {}).get(hand)
    if rows.ndim != 3 or at is None or not 0 <= at < rows.shape[0]:
        raise DatasetError(f"{where}: meta raw_paired names row {at!r} of raw rows shaped {rows.shape}")
    return rows[at]


MAP_SOURCES = ("auto", "stored", "raw")


def serves_maps_from_raw(manifest: dict, map_source: str = "auto", where: str = "") -> bool:
    """Whether the loaders serve a version's maps rendered from raw rows (else the stored EXR is decoded).

    THE rule, shared by the torch datasets and `htdata validate` (which checks that both agree):
    "auto" (the loaders' default) renders from raw rows when the version stores them (format 3)
    and was rasterised in nearest mode, where rendering is a gather of the exact normalised values;
    "stored" never does; "raw" always does (and a sample without raw rows is an error).
    A version whose maps are not stored (codec.tactile.maps = "raw") is always served from raw rows;
    "stored" on it is an error.
    """
    if map_source not in MAP_SOURCES:
        raise ValueError(f"map_source must be one of {MAP_SOURCES}, got {map_source!r}")
    if not maps_stored(manifest):
        if map_source == "stored":
            raise ValueError(f"{where or 'dataset'}: map_source='stored', but this version stores no tactile maps (ingested with [tactile] "
                             "maps = \"raw\"); its maps are rendered from the raw rows: use map_source='auto' or 'raw'")
        return True
    if map_source != "auto":
        return map_source == "raw"
    return (manifest["codec"]["tactile"].get("raster_mode") == "nearest"
            and manifest.get("format_version", 1) >= 3)


def paired_source_row(members: dict[str, bytes], hand: str, where: str) -> int:
    """The source row number of the raw row paired with a sample's frame (meta raw_row / raw_paired)."""
    meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], where)
    rows = (meta.get("raw_row") or {}).get(hand)
    at = (meta.get("raw_paired") or {}).get(hand, 0)
    if not rows or not 0 <= at < len(rows):
        raise DatasetError(f"{where}: meta raw_row / raw_paired do not name the paired {hand} row")
    return int(rows[at])


def apply_paired(normaliser, members: dict[str, bytes], hand: str, where: str):
    """normaliser.apply on a sample's paired raw row (with its source row number when the baseline drifts)."""
    return apply_paired_many(normaliser, [members], hand, where)


def apply_paired_many(normaliser, members_list: list[dict[str, bytes]], hand: str, where: str):
    """normaliser.apply on the paired raw rows of several samples of one episode hand, in one call."""
    rows = ([paired_source_row(m, hand, where) for m in members_list]
            if normaliser.cfg.baseline == "drift" else None)
    return normaliser.apply(np.stack([paired_row(m, hand, where) for m in members_list]), rows=rows)


class RawMapRenderer:
    """Maps from the paired raw rows (see the module docstring); one normaliser per episode hand, cached."""

    def __init__(self, reader):
        self.reader = reader
        self.mode = reader.manifest["codec"]["tactile"].get("raster_mode", "nearest")
        self._layouts: dict = {}
        self._rasters: dict = {}
        self._normalisers: dict = {}

    def parts_for(self, episode: int, hand: str):
        """(Normaliser with the episode's calibration, Rasteriser of its layout) for one episode hand."""
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
        """(224,224) float32 map from `members` (json + raw_<hand>.npy) of a sample of episode position `episode`."""
        normaliser, raster = self.parts_for(episode, hand)
        values, _ = apply_paired(normaliser, members, hand, where)
        return check_finite_maps(raster.render(values)[0], f"{where} ({hand})")

    def render_many(self, episode: int, hand: str, members_list: list[dict[str, bytes]], where: str = "sample"
                    ) -> np.ndarray:
        """(n,224,224) float32 maps of n samples of one episode hand: one normalise and one rasterise call."""
        normaliser, raster = self.parts_for(episode, hand)
        values, _ = apply_paired_many(normaliser, members_list, hand, where)
        return check_finite_maps(raster.render(values), f"{where} ({hand})")

    def sample_map(self, index: int, hand: str) -> np.ndarray:
        row, key, members = self.reader.read_sample(index, (JSON_MEMBER, raw_member(hand)))
        if raw_member(hand) not in members:
            raise KeyError(f"{self.reader.root}: {key} has no raw {hand} rows")
        return self.render(row.episode, hand, members, f"{self.reader.root}: {key}")
