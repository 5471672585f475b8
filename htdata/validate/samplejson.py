"""The sample JSON of one sample: its schema, and agreement with the index row and the members present.

Split from structure.py (which checks the dataset's files and tar headers);
called per sample inside a shard worker (htdata/validate/shards.py).
"""

from __future__ import annotations

from functools import lru_cache

from htdata.format.codec import decode_json
from htdata.format.table import HANDS, JSON_MEMBER, SIZE_FIELDS, tactile_member
from htdata.resources import load_schema, validate_json
from htdata.validate.report import Recorder


@lru_cache(maxsize=1)
def _sample_validator():
    """One compiled validator per process: building it per sample costs ~1 ms each."""
    import jsonschema


    return jsonschema.Draft202012Validator(load_schema("sample"))


def check_sample_json(rec: Recorder, data: bytes, key: str, eid: str, frame: int, row,
                      where: dict, map_members: dict[str, str] | None = None) -> dict | None:
    """The sample JSON: schema, key/episode/frame as indexed, hands as the map members present (`map_members`).

    Returns the parsed JSON, or None when its timestamps cannot be trusted.
    """
    where_json = f"{key}.{JSON_MEMBER}"
    try:
        meta = decode_json(data, where_json)
        if not _sample_validator().is_valid(meta):
            validate_json(meta, "sample", where=where_json)  # raises with the first error
    except ValueError as exc:
        rec.fail("sample_json", str(exc), **where)
        return None
    rec.checked["sample_json"] += 1
    for field_name, expected in (("key", key), ("episode_id", eid), ("frame_index", frame)):
        if meta[field_name] != expected:
            rec.fail("sample_json_mismatch", f"{where_json}: {field_name} disagrees with the index",
                     **where, expected=expected, found=meta[field_name])
    for hand in HANDS:
        member = (map_members or {}).get(hand, tactile_member(hand))
        has_map = int(row[SIZE_FIELDS[member]]) > 0
        if bool(meta["hands"][hand]) != has_map:
            rec.fail("sample_hands", f"{where_json}: hands.{hand}={meta['hands'][hand]} but the "
                     f"{member} member is {'present' if has_map else 'absent'}",
                     **where, expected=has_map, found=meta["hands"][hand])
        if has_map and hand not in meta["t_tactile_ns"]:
            rec.fail("sample_json", f"{where_json}: no t_tactile_ns for the {hand} hand", **where)
            return None
    return meta
