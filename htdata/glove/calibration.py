"""Calibrations: how raw glove values became the stored [0,1] maps, recorded exactly.

A calibration is a glove layout's `NormaliseConfig` (convention, max,
baseline, clip, scale, noise floor) plus where it came from. Its id is a
content hash, so the same settings in two ingests are one calibration and a
recalibrated glove is a new one. The manifest lists the calibrations its
episodes use (`"calibrations": {id: entry}`; `revision` counts, per layout,
the distinct calibrations the dataset has had, 1 for the first). Each
episode record names its calibration per hand and, when the calibration
fits per-episode arrays (a baseline, a noise floor from the rest window),
carries them as base64 little-endian float32 (`calibration_fit`; "zlib:" + the
base64 of its zlib stream where that saves a quarter or more, `encode_array`), so
`episode_normaliser` rebuilds the exact normaliser the ingest used and the
stored raw rows (members raw_<hand>.npy) reproduce the stored maps without
the sources (htdata.curate.renormalise).

Every record that decides a served value is verified, not trusted
(`record_errors`, run when a reader opens a version and by `htdata
validate`): a calibration's id is recomputed from its entry, and each
episode hand's fitted arrays carry their own digest
(`calibration_fit_sha256`). Each episode record also carries
`taxels_sha256`: per hand, a digest of the normalised live taxels every
paired frame's map is rasterised from (`taxel_digest`), so `validate --deep`
can prove that the raw rows under the recorded calibration give the maps
the ingest made, whether or not the maps are stored. It is taken over the
taxels, not the 224x224 maps: the same proof (the raster is the layout
document's, whose sha256 the manifest lists) at 1/200th of the hashing
(sha256 of one float32 map costs ~0.6 ms here, half an EXR encode).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import zlib

import numpy as np

from htdata.errors import DatasetError, RecordMismatch
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.glove.normalisesettings import NormaliseSettings


def calibration_id(layout_id: str, cfg: NormaliseConfig) -> str:
    """Content id of (layout, settings): 12 hex digits of a sha256."""
    text = json.dumps({"layout": layout_id, **cfg.to_dict()}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def calibration_entry(layout_id: str, cfg: NormaliseConfig, origin: str) -> dict:
    """The manifest entry of one calibration (revision filled in by `merge_calibrations`)."""
    return {"layout": layout_id, **cfg.to_dict(), "from": origin,
            "fitted_per_episode": bool(cfg.fits)}


def episode_calibrations(normalising: NormaliseSettings, layouts: dict) -> dict[str, dict]:
    """{id: manifest entry} of the calibrations a pipeline applies to these layouts (hand -> Layout).

    `normalising`: the pipeline's glove.normalisesettings.NormaliseSettings (the ingest's and
    renormalise's alike).
    """
    out = {}
    for layout in layouts.values():
        cfg = normalising.normalise_for(layout)
        origin = (f"pipeline {normalising.name!r} [normalise.{layout.layout_id}]"
                  if layout.layout_id in normalising.normalise else f"layout {layout.layout_id!r} value block")
        out[calibration_id(layout.layout_id, cfg)] = calibration_entry(layout.layout_id, cfg, origin)
    return out


def config_of(entry: dict) -> NormaliseConfig:
    """A manifest calibration entry -> its NormaliseConfig (validated)."""
    return NormaliseConfig.from_record(entry).validate()


ZLIB_PREFIX = "zlib:"
# A fitted array is stored compressed only where that saves at least this share: the pooled rest's shift knots
# (one value over the grid per knot) and the taxel calibration's gain shrink ~100x, and they made 97% of a raw
# glove's episode record, rewritten with every version (bench section "size"); a per-cell floor does not.
ZLIB_MIN_SAVING = 0.25
MAX_FIT_BYTES = 256 << 20    # a fitted array never decompresses past this (a record is data, not a zip bomb)


def encode_array(arr: np.ndarray) -> str:
    """float32 little-endian bytes as base64, or ZLIB_PREFIX + the base64 of their zlib stream when that is at
    least ZLIB_MIN_SAVING smaller (deterministic: the same array, the same text)."""
    raw = np.ascontiguousarray(arr, dtype="<f4").tobytes()
    packed = zlib.compress(raw, 6)
    if len(packed) <= (1 - ZLIB_MIN_SAVING) * len(raw):
        return ZLIB_PREFIX + base64.b64encode(packed).decode("ascii")
    return base64.b64encode(raw).decode("ascii")


def _array_bytes(text: str, where: str) -> bytes:
    """The float32 bytes of an `encode_array` text (DatasetError naming `where` when they do not decode)."""
    packed = isinstance(text, str) and text.startswith(ZLIB_PREFIX)
    unpack = zlib.decompressobj()
    try:
        data = base64.b64decode(text[len(ZLIB_PREFIX):] if packed else text, validate=True)
        if packed:
            data = unpack.decompress(data, MAX_FIT_BYTES + 1)
    except (binascii.Error, ValueError, TypeError, zlib.error) as exc:
        raise DatasetError(f"{where}: not a base64 (or zlib: base64) float32 array ({exc})") from exc
    if packed and (len(data) > MAX_FIT_BYTES or not unpack.eof):
        raise DatasetError(f"{where}: its zlib stream is incomplete or inflates past {MAX_FIT_BYTES} bytes")
    return data


def decode_array(text: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """`encode_array` text -> array of `shape`; a leading -1 takes any whole number of (shape[1:]) items."""
    data = _array_bytes(text, where)
    item = 4 * int(np.prod(shape[1:] if shape and shape[0] == -1 else shape))
    if (shape and shape[0] == -1 and (not data or len(data) % max(item, 1))) or \
            (not (shape and shape[0] == -1) and len(data) != item):
        raise DatasetError(f"{where}: {len(data)} bytes, expected {'x'.join(str(v) for v in shape)} float32")
    return np.frombuffer(data, dtype="<f4").reshape(shape).astype(np.float32)


def _fit_shape(name: str, cfg: NormaliseConfig, grid: tuple[int, int]) -> tuple[int, ...]:
    """Stored shape of a fitted array: the drift baseline is (K,H,W) knots and knot_rows (K,)."""
    if name == "knot_rows":
        return (-1,)
    if name == "baseline" and cfg.knotted:
        return (-1, *grid)
    return grid


def fit_record(normaliser: Normaliser) -> dict:
    """An episode hand's fitted arrays for the episode record ({} when the calibration fits nothing)."""
    return {name: encode_array(arr) for name, arr in normaliser.fitted().items()}


def episode_normaliser(manifest: dict, episode: dict, hand: str, layout) -> Normaliser:
    """The normaliser the ingest used for `hand` of `episode` (settings from the manifest, fitted arrays restored).

    Raises ValueError naming the episode when the dataset predates
    calibrations (format < 3) or the record names an unknown calibration.
    """
    where = f"episode {episode.get('episode_id')!r} {hand} hand"
    cal_id = (episode.get("calibration") or {}).get(hand)
    if cal_id is None:
        raise DatasetError(f"{where}: no calibration recorded (datasets of format < 3 have none: re-ingest them)")
    entry = manifest.get("calibrations", {}).get(cal_id)
    if entry is None:
        raise DatasetError(f"{where}: calibration {cal_id} is not in the manifest's calibrations")
    normaliser = Normaliser(config_of(entry), layout)
    fit = (episode.get("calibration_fit") or {}).get(hand, {})
    grid = normaliser.grid
    normaliser.restore({k: decode_array(v, _fit_shape(k, normaliser.cfg, grid), f"{where} calibration_fit.{k}")
                        for k, v in fit.items()})
    return normaliser


def merge_calibrations(parent: dict, new: dict, used: set[str]) -> dict:
    """The calibrations of a new version: parent's and new entries that `used` ids name, revisions numbered.

    A new id gets revision = 1 + the highest revision the parent listed for
    its layout (so revisions count recalibrations over the dataset's life).
    """
    merged = {k: v for k, v in parent.items() if k in used}
    for cal_id, entry in sorted(new.items()):
        if cal_id not in used:
            continue
        if cal_id in parent:
            merged[cal_id] = parent[cal_id]
            continue
        seen = [e.get("revision", 1) for e in list(parent.values()) + list(merged.values())
                if e["layout"] == entry["layout"]]
        merged[cal_id] = {**entry, "revision": max(seen, default=0) + 1}
    return dict(sorted(merged.items()))


def fit_digest(fit: dict) -> str:
    """Digest of one episode hand's `calibration_fit` entry (its base64 arrays, by name)."""
    return hashlib.sha256(json.dumps(fit, sort_keys=True).encode()).hexdigest()[:16]


def fit_digests(fits: dict) -> dict:
    """{hand: digest} for an episode record's `calibration_fit` ({hand: {name: base64}})."""
    return {hand: fit_digest(fit) for hand, fit in sorted(fits.items())}


def taxel_digest(live_rows: list[np.ndarray]) -> str:
    """Digest of an episode hand's normalised live taxels, paired frames in sample order ((n, L) blocks).

    float32 little-endian, "+ 0.0" so -0.0 and 0.0 (the same map) hash alike.
    """
    h = hashlib.sha256()
    for block in live_rows:
        h.update((np.asarray(block, dtype="<f4") + np.float32(0.0)).astype("<f4", copy=False).tobytes())
    return h.hexdigest()[:16]


# The episode digests a version's manifest may say every record of it carries ("record_digests", written by
# every commit: htdata/store/snapshot.py): a record without one is then an edited record, not one written
# before the digest existed (the only reason a record may lack it).
DIGEST_FIELDS = ("calibration_fit_sha256", "taxels_sha256")


def carried_digests(episodes: list[dict]) -> list[str]:
    """The DIGEST_FIELDS every one of `episodes` carries (for each fitted hand / each hand it has): the
    manifest's "record_digests" of a version holding them."""
    out = []
    if all(set(ep.get("calibration_fit") or {}) <= set(ep.get("calibration_fit_sha256") or {}) for ep in episodes):
        out.append("calibration_fit_sha256")
    if all(set(ep.get("layouts") or {}) <= set(ep.get("taxels_sha256") or {}) for ep in episodes):
        out.append("taxels_sha256")
    return out


def _missing_digests(ep: dict, required, episodes_where: str) -> list[str]:
    """One line per digest the manifest requires that `ep` lacks."""
    lines, eid = [], ep.get("episode_id")
    for field, covers in (("calibration_fit_sha256", ep.get("calibration_fit") or {}),
                          ("taxels_sha256", ep.get("layouts") or {})):
        missing = sorted(set(covers) - set(ep.get(field) or {})) if field in required else []
        if missing:
            lines.append(f"{episodes_where}: episode {eid!r} has no {field} for {', '.join(missing)}, which its "
                         f"version's manifest says every record carries (record_digests): the record was edited "
                         f"after it was written")
    return lines


def record_errors(calibrations: dict, episodes: list[dict], manifest_where: str, episodes_where: str,
                  required=()) -> list[str]:
    """One line per calibration record whose content no longer matches its id or digest (empty: all sound).

    Checks each manifest calibration's id against its settings (an edited `max_value` changes every map
    rendered or renormalised under it) and each episode's `calibration_fit` against its recorded
    `calibration_fit_sha256`. A digest is absent in datasets written before it existed (nothing to check),
    unless `required` (the manifest's "record_digests") names it: a record without it is then a failure.
    """
    errors = []
    for cal_id, entry in sorted(calibrations.items()):
        try:
            got = calibration_id(entry["layout"], config_of(entry))
        except (KeyError, TypeError, ValueError) as exc:
            errors.append(f"{manifest_where}: calibration {cal_id}: unreadable entry ({exc})")
            continue
        if got != cal_id:
            errors.append(f"{manifest_where}: calibration {cal_id} (layout {entry['layout']!r}): its settings hash "
                          f"to {got}, not its id: the record was changed after it was written")
    for ep in episodes:
        errors += _missing_digests(ep, required, episodes_where)
        recorded = ep.get("calibration_fit_sha256")
        if recorded is None:
            continue
        got = fit_digests(ep.get("calibration_fit") or {})
        for hand in sorted(set(recorded) | set(got)):
            if recorded.get(hand) != got.get(hand):
                errors.append(f"{episodes_where}: episode {ep.get('episode_id')!r} calibration_fit.{hand}: digest "
                              f"{got.get(hand)} differs from the recorded {recorded.get(hand)}: the fitted arrays "
                              f"were changed after ingest")
    return errors


def refuse_mismatched(calibrations: dict, episodes: list[dict], manifest_where: str, episodes_where: str,
                      required=()) -> None:
    """RecordMismatch naming the first record `record_errors` finds (a reader opening a version)."""
    errors = record_errors(calibrations, episodes, manifest_where, episodes_where, required)
    if errors:
        more = f" (+{len(errors) - 1} more: htdata validate lists them)" if len(errors) > 1 else ""
        raise RecordMismatch(errors[0] + more)
