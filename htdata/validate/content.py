"""Content: decode samples and check what they hold.

Every sample with `--deep`, else a seeded fraction plus the first frame of
every episode (`decode_mask`). RGB decodes to (224,224,3) uint8; each tactile
EXR is half (224,224), finite, in [0,1] and zero outside the coverage of the
hand's layout; bend vectors are finite 1-D float vectors; raw glove rows
(format 3) are (R,H,W) numeric arrays whose R rows the JSON member names
(raw_t_ns, raw_row, raw_paired). Decoded tactile maps feed the sensor
accumulator (htdata/validate/sensors.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from htdata.format.canvas import CANVAS, MAP_SHAPE

# Maps are checked as stored (half or float pixels, before conversion): decode_exr_pixels; every other
# member decodes through the member table like every reader.
from htdata.format.codec import decode_png_u8
from htdata.format.imageheader import DeclaredShapeError
from htdata.format.table import HANDS, JSON_MEMBER, RGB_MEMBER, bend_member, decode_member, raw_member, tactile_member
from htdata.format.tactilecodec import decode_exr_pixels
from htdata.store.confine import inside
from htdata.validate.geometry import CoverageGeometry
from htdata.validate.report import Check, Recorder
from htdata.validate.sensors import accumulate, hand_key

RGB_SHAPE = (CANVAS, CANVAS, 3)
# manifest codec.tactile.pixel_type -> stored pixel type of the tactile maps (htdata/glove/codecrule.py)
TACTILE_PIXELS = {"half": np.dtype(np.float16), "float": np.dtype(np.float32)}


def layout_maps(root: Path, manifest: dict, check: Check) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """(layout id -> coverage bool map, canonical region ids) as the manifest lists them."""
    coverage = {}
    for layout_id, entry in manifest["layouts"].items():
        try:
            path = inside(root, entry["coverage"], f"layouts.{layout_id}.coverage")
            coverage[layout_id] = decode_png_u8(Path(path).read_bytes(), str(path)) > 0
        except (OSError, ValueError) as exc:
            check.fail("coverage_unreadable", f"layout {layout_id}: {exc}", file=entry["coverage"])
    region_map = None
    try:
        path = inside(root, manifest["canonical"]["regions"], "canonical.regions")
        region_map = decode_png_u8(Path(path).read_bytes(), str(path))
    except (OSError, ValueError) as exc:
        check.fail("regions_unreadable", f"canonical region map: {exc}", file=manifest["canonical"]["regions"])
    return coverage, region_map


def decode_mask(frames: np.ndarray, deep: bool, sample_frac: float, seed: int) -> np.ndarray:
    """Rows whose content is decoded: all with `deep`, else a seeded fraction + each episode's first frame."""
    n = len(frames)
    if deep:
        return np.ones(n, bool)
    rng = np.random.default_rng(seed)
    mask = rng.random(n) < sample_frac
    mask |= frames == 0
    return mask


def check_content(geometry: dict[str, CoverageGeometry], rec: Recorder, key: str, where: dict,
                  members: dict[str, bytes], hands_present: list[str], sensor: dict,
                  pixel_type: str = "half") -> None:
    """Decode one sample's members and check shapes, dtypes, values and coverage."""
    rec.checked["samples_decoded"] += 1
    if RGB_MEMBER in members or not _tactile_only(members):
        _check_rgb(rec, key, where, members)
    for hand in hands_present:
        _check_tactile(geometry, rec, key, where, hand, members[tactile_member(hand)], sensor,
                       TACTILE_PIXELS[pixel_type])
    for hand in HANDS:
        member = bend_member(hand)
        if member in members:
            _check_bend(rec, key, member, where, hand, members[member])
        if raw_member(hand) in members:
            _check_raw(rec, key, where, hand, members)


def _tactile_only(members: dict[str, bytes]) -> bool:
    """True for a glove-only recording's sample (its JSON says so): no RGB member is expected."""
    try:
        return bool(decode_member(JSON_MEMBER, members[JSON_MEMBER], "sample").get("tactile_only")) if JSON_MEMBER in members else False
    except ValueError:
        return False


def _check_rgb(rec: Recorder, key: str, where: dict, members: dict[str, bytes]) -> None:
    if RGB_MEMBER not in members:
        rec.fail("rgb_missing", f"{key}: no {RGB_MEMBER} member", **where)
        return
    try:
        rgb = decode_member(RGB_MEMBER, members[RGB_MEMBER], key)
    except DeclaredShapeError as exc:      # refused by its header, undecoded
        rec.fail("rgb_shape", str(exc), **where, expected=f"{RGB_SHAPE[:2]}", found=f"{exc.found}")
        return
    except ValueError as exc:
        rec.fail("rgb_decode", str(exc), **where)
        return
    if rgb.shape != RGB_SHAPE or rgb.dtype != np.uint8:
        rec.fail("rgb_shape", f"{key}.{RGB_MEMBER} decodes to {rgb.shape} {rgb.dtype}",
                 **where, expected=f"{RGB_SHAPE} uint8", found=f"{rgb.shape} {rgb.dtype}")


def _check_tactile(geometry: dict[str, CoverageGeometry], rec: Recorder, key: str, where: dict, hand: str,
                   data: bytes, sensor: dict, pixels_dtype: np.dtype) -> None:
    """One tactile member: stored as the manifest's pixel type (224,224), finite, in [0,1], zero outside coverage."""
    name = f"{key}.{tactile_member(hand)}"
    rec.checked["tactile_maps_decoded"] += 1
    try:
        pixels = decode_exr_pixels(data, name)
    except DeclaredShapeError as exc:      # refused by its header, undecoded
        rec.fail("tactile_shape", str(exc), **where, hand=hand, expected=f"{MAP_SHAPE}", found=f"{exc.found}")
        return
    except ValueError as exc:
        rec.fail("tactile_decode", str(exc), **where, hand=hand)
        return
    if pixels.shape != MAP_SHAPE or pixels.dtype != pixels_dtype:
        rec.fail("tactile_shape", f"{name}: {pixels.shape} {pixels.dtype}", **where, hand=hand,
                 expected=f"{MAP_SHAPE} {pixels_dtype}", found=f"{pixels.shape} {pixels.dtype}")
        return
    check_map_values(geometry, rec, name, where, hand, pixels.astype(np.float32), sensor)


def check_map_values(geometry: dict[str, CoverageGeometry], rec: Recorder, name: str, where: dict, hand: str,
                     tmap: np.ndarray, sensor: dict) -> None:
    """A (224,224) float32 map, stored or rendered from raw rows: finite, in [0,1], zero outside coverage."""
    finite = np.isfinite(tmap)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        rec.fail("tactile_nonfinite", f"{name}: {int((~finite).sum())} NaN/Inf value(s), first at row "
                 f"{bad[0]}, col {bad[1]}", **where, hand=hand, expected="finite",
                 found=f"{int(np.isnan(tmap).sum())} NaN, {int(np.isinf(tmap).sum())} Inf")
        return
    lo, hi = float(tmap.min()), float(tmap.max())
    if lo < 0.0 or hi > 1.0:
        rec.fail("tactile_range", f"{name}: values outside [0,1]", **where, hand=hand,
                 expected="[0, 1]", found=f"[{lo:.6g}, {hi:.6g}]")
    geo = geometry.get(hand_key(where["episode"], hand))
    if geo is None:
        rec.fail("coverage_missing", f"{name}: no coverage map for the {hand} hand's layout", **where, hand=hand)
        return
    flat = tmap.ravel()
    covered = flat[geo.idx]
    n_outside = int(np.count_nonzero(flat)) - int(np.count_nonzero(covered))
    if n_outside:
        bad = np.argwhere((~geo.mask) & (tmap != 0))[0]
        rec.fail("tactile_outside_coverage", f"{name}: {n_outside} non-zero pixel(s) outside the layout's "
                 f"coverage, first at row {bad[0]}, col {bad[1]}", **where, hand=hand,
                 expected="0 outside coverage", found=f"{n_outside} pixels")
    accumulate(sensor, where["episode"], hand, where["frame"], covered, geo, hi)


def _check_bend(rec: Recorder, key: str, member: str, where: dict, hand: str, data: bytes) -> None:
    name = f"{key}.{member}"
    try:
        bend = decode_member(member, data, key)
    except ValueError as exc:
        rec.fail("bend_decode", str(exc), **where, hand=hand)
        return
    if bend.ndim != 1 or not np.issubdtype(bend.dtype, np.floating) or not np.isfinite(bend).all():
        rec.fail("bend_values", f"{name}: expected a finite 1-D float vector",
                 **where, hand=hand, found=f"{bend.shape} {bend.dtype}")


def _check_raw(rec: Recorder, key: str, where: dict, hand: str, members: dict[str, bytes]) -> None:
    """Raw rows: a numeric (R,H,W) array; the JSON member names each row and the paired one."""
    name = f"{key}.{raw_member(hand)}"
    try:
        rows = decode_member(raw_member(hand), members[raw_member(hand)], key)
        meta = decode_member(JSON_MEMBER, members[JSON_MEMBER], key) if JSON_MEMBER in members else {}
    except ValueError as exc:
        rec.fail("raw_decode", str(exc), **where, hand=hand)
        return
    if rows.ndim != 3 or not (np.issubdtype(rows.dtype, np.number)) or rows.shape[0] == 0:
        rec.fail("raw_shape", f"{name}: expected (R,H,W) numeric rows, R >= 1", **where, hand=hand,
                 found=f"{rows.shape} {rows.dtype}")
        return
    named = [len((meta.get(field) or {}).get(hand, [])) for field in ("raw_t_ns", "raw_row")]
    paired = (meta.get("raw_paired") or {}).get(hand)
    if named != [rows.shape[0]] * 2 or not (isinstance(paired, int) and 0 <= paired < rows.shape[0]):
        rec.fail("raw_meta", f"{name}: {rows.shape[0]} rows, but the JSON member names {named[0]} timestamps, "
                 f"{named[1]} source rows and paired row {paired!r}", **where, hand=hand)
