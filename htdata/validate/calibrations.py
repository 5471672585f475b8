"""The records that decide a served value, recomputed: calibration ids, fitted-array digests, taxel digests.

A map served from raw rows (and every map `htdata renormalise` writes) is a function of the raw rows, the
manifest's calibration entry, the episode's `calibration_fit` and the layout. The sha256 chain of the
manifest covers the files, not what is in them: a hand-edited `max_value` with the sha256 re-sealed was
"sound". Here (htdata/glove/calibration.py `record_errors`, the same check a reader runs when it opens a
version): each calibration id is recomputed from its settings and each fit from its digest, in every
validate. With --deep, each episode hand's `taxels_sha256` (recorded at ingest) is recomputed from the
stored raw rows under the recorded calibration: a maps = "raw" version, whose maps exist only as
rendered, is then checked as strongly as a stored one is by the stored-vs-rendered cross-check.
"""

from __future__ import annotations

from htdata.format.table import HANDS, JSON_MEMBER, SEGMENTS_DIR, raw_member
from htdata.glove.calibration import record_errors, taxel_digest
from htdata.read.rawstream import RawMapRenderer, apply_paired_many
from htdata.read.reader import DatasetReader
from htdata.store.versions import manifest_path
from htdata.validate.report import Check

BATCH = 256


def check_calibration_records(root, manifest: dict, episodes: list[dict], check: Check) -> bool:
    """Fail "calibration_record" once per mismatching record; True when every record is sound."""
    where = str(manifest_path(root, manifest.get("version")))
    errors = record_errors(manifest.get("calibrations", {}), episodes, where, manifest.get("episodes_file", SEGMENTS_DIR),
                           manifest.get("record_digests", ()))
    for line in errors:
        check.fail("calibration_record", line)
    check.checked["calibration_records"] += len(manifest.get("calibrations", {})) + len(episodes)
    return not errors


def check_taxel_digests(root, version: int | None, check: Check) -> None:
    """Recompute every recorded `taxels_sha256` from the raw rows (one pass over the raw members)."""
    reader = DatasetReader(root, version=version)
    renderer = RawMapRenderer(reader)
    for pos, ep in enumerate(reader.episodes):
        for hand, recorded in sorted((ep.get("taxels_sha256") or {}).items()):
            eid = ep["episode_id"]
            try:
                got = _episode_digest(reader, renderer, pos, hand)
            except (ValueError, KeyError) as exc:
                check.fail("taxels_sha256", f"episode {eid!r} {hand}: taxels not re-derived from the raw rows: {exc}",
                           episode=eid, hand=hand)
                continue
            if got is None:     # keep_raw = false: no raw rows to re-derive the taxels from
                continue
            check.checked["taxel_digests"] += 1
            if got != recorded:
                check.fail("taxels_sha256", f"episode {eid!r} {hand}: the raw rows under the recorded calibration "
                           f"give taxels with digest {got}, the ingest recorded {recorded}: the maps served are "
                           f"not the ones the ingest made", episode=eid, hand=hand)


def _episode_digest(reader: DatasetReader, renderer: RawMapRenderer, pos: int, hand: str) -> str | None:
    normaliser, _ = renderer.parts_for(pos, hand)
    first, n = reader.episode_range(pos)
    blocks, batch = [], []

    def flush() -> None:
        if batch:
            values, _ = apply_paired_many(normaliser, batch, hand, f"{reader.episodes[pos]['episode_id']} {hand}")
            blocks.append(values[:, normaliser.live_mask])
            batch.clear()

    for i in range(first, first + n):
        members = reader.sample(i, (JSON_MEMBER, raw_member(hand)))
        if raw_member(hand) in members:
            batch.append(members)
            if len(batch) >= BATCH:
                flush()
    flush()
    return taxel_digest(blocks) if blocks else None


def has_taxel_digests(episodes: list[dict]) -> bool:
    return any(set(ep.get("taxels_sha256") or {}) & set(HANDS) for ep in episodes)

