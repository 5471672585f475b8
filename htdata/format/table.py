"""The on-disk format of an htdata dataset, in one place (docs/FORMAT.md "Dataset on disk").

Everything a writer and a reader must agree on lives here: the file names of
a committed dataset, the member table and the index dtype derived from it
(the canvas side and the hand names: canvas.py, which the codecs need).
Like webdataset's `writer.make_handlers` / `autodecode`, ONE table maps a member suffix to its index column and codec;
`encode_sample` / `decode_sample` walk it, so adding a stored member is one
row in MEMBERS (plus its codec kind in `htdata.format.codec.MEMBER_CODECS` when the
kind is new). Member order in the table is the order inside a sample's tar
entries and the order of the index's size columns: never reorder it, append.

A sample in memory (what `decode_sample` returns and `encode_sample` takes):
    {"meta": dict, "rgb": (224,224,3) uint8,
     "tactile": {hand: (224,224) float32}, "bend": {hand: (K,) float32},
     "raw": {hand: (R,H,W) source dtype}}
with only the members the sample holds. `raw` holds the glove's rows exactly
as read (format 3): the row paired with this frame (position
meta["raw_paired"][hand]) and every unpaired row of the full-rate stream
whose time falls after this frame and before the next one (their timestamps
and source row numbers in meta["raw_t_ns"][hand] / meta["raw_row"][hand]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from htdata._moved import moved_name
from htdata.errors import DatasetError
from htdata.format.canvas import HANDS
from htdata.format.codec import MEMBER_CODECS

FORMAT = "htdata"
# 4: a version's records as shared immutable segments (htdata/store/segments.py), not its own
# episodes.jsonl + index.npy; 3: raw glove rows (members raw_{hand}.npy) + calibrations; 2: versions
# (htdata/store/versions.py); 1: one unversioned commit. Indexes of 1 and 2 lack the raw size columns
# (LEGACY_INDEX_DTYPE). Samples and shards are the same in 3 and 4.
FORMAT_VERSION = 4
READABLE_FORMAT_VERSIONS = (1, 2, 3, 4)

# -- files of a committed dataset -------------------------------------------
MANIFEST_FILE = "dataset.json"     # written last: its presence means "committed"
EPISODES_FILE = "episodes.jsonl"
INDEX_FILE = "index.npy"
SHARDS_DIR = "shards"
SEGMENTS_DIR = "segments"          # format 4: the versions' episode records and index rows, shared
LAYOUTS_DIR = "layouts"
CANONICAL_FILE = "canonical_hand.json"
REGIONS_FILE = "regions.png"       # per-place region ids (0 = outside the hand)
PARTS_FILE = "parts.png"           # part ids: thumb=1 .. palm=6 (stage-2 masking)
SPLITS_DIR = "splits"
REPORTS_DIR = "reports"
INGEST_REPORT = f"{REPORTS_DIR}/ingest.json"
VALIDATE_REPORT = f"{REPORTS_DIR}/validate.json"   # default report of `htdata validate`
WORK_DIR = ".work"                 # resume state and temp files of a running ingest
STATS_DIR = "stats"                # per-episode stats cache (htdata/inspect/stats.py)


@dataclass(frozen=True)
class Member:
    """One stored member of a sample: `{key}.{suffix}` in the tar, `column` in index.npy.

    `field` (and `hand` for per-hand members) is where its value sits in a
    decoded sample; `kind` names its codec in `htdata.format.codec.MEMBER_CODECS`;
    `since` is the format version that added it (its index column exists from then on).
    """
    suffix: str
    column: str
    field: str
    kind: str
    hand: str | None = None
    since: int = 1


def _per_hand(stem: str, ext: str, field: str, kind: str, since: int = 1) -> tuple[Member, ...]:
    return tuple(Member(f"{stem}_{h}.{ext}", f"size_{stem}_{h}", field, kind, h, since) for h in HANDS)


MEMBERS: tuple[Member, ...] = (
    Member("json", "size_json", "meta", "json"),
    Member("rgb.jpg", "size_rgb", "rgb", "jpeg"),
    *_per_hand("tactile", "exr", "tactile", "exr"),
    *_per_hand("bend", "npy", "bend", "npy"),
    *_per_hand("raw", "npy", "raw", "npy", since=3),
)
JSON_MEMBER = MEMBERS[0].suffix
RGB_MEMBER = MEMBERS[1].suffix
MEMBER_ORDER = tuple(m.suffix for m in MEMBERS)
MEMBER_BY_SUFFIX = {m.suffix: m for m in MEMBERS}
SIZE_FIELDS = {m.suffix: m.column for m in MEMBERS}     # member suffix -> index size column
PER_HAND_FIELDS = tuple(dict.fromkeys(m.field for m in MEMBERS if m.hand))

# index.npy, little endian, one row per sample; a size of 0 = member absent.
_INDEX_HEAD = [
    ("shard", "<u4"),      # position in manifest["shards"]
    ("offset", "<u8"),     # byte offset of the sample's FIRST member header
    ("episode", "<u4"),    # position in episodes.jsonl
    ("frame", "<u4"),
]


def index_dtype(format_version: int) -> np.dtype:
    """The index.npy dtype of a format version: the head, then a size column per member it has."""
    return np.dtype([*_INDEX_HEAD, *[(m.column, "<u4") for m in MEMBERS if m.since <= format_version]])


INDEX_DTYPE = index_dtype(FORMAT_VERSION)
# Every readable version's index dtype: htdata.store.manifest converts an older one on load (absent
# members' sizes 0), so adding a member (a new format version) keeps every existing index readable.
INDEX_DTYPES = {v: index_dtype(v) for v in READABLE_FORMAT_VERSIONS}
LEGACY_INDEX_DTYPE = INDEX_DTYPES[2]    # formats 1 and 2: before the raw members


def tactile_member(hand: str) -> str:
    return _hand_member("tactile", hand)


def bend_member(hand: str) -> str:
    return _hand_member("bend", hand)


def raw_member(hand: str) -> str:
    return _hand_member("raw", hand)


def _hand_member(field: str, hand: str) -> str:
    for m in MEMBERS:
        if m.field == field and m.hand == hand:
            return m.suffix
    raise ValueError(f"no {field} member for hand {hand!r} (hands: {HANDS})")


@dataclass(frozen=True)
class CodecSettings:
    """The per-dataset codec choices an encoder needs (recorded in the manifest's "codec").

    `tactile_pixel_type` is the EXR pixel type of the maps ("half" or
    "float"), already resolved: the pipeline's `[codec] tactile = "auto"` is
    turned into one by the rule in htdata/glove/codecrule.py.
    """
    tactile_compression: str = "zip"
    rgb_quality: int = 95
    tactile_pixel_type: str = "half"


def encode_sample(sample: dict, settings: CodecSettings, where: str) -> dict[str, bytes]:
    """Decoded-sample dict -> {suffix: bytes}, in member order; `where` names the sample in errors."""

    members = {}
    for m in MEMBERS:
        value = sample.get(m.field)
        if m.hand is not None:
            value = None if value is None else value.get(m.hand)
        if value is not None:
            members[m.suffix] = MEMBER_CODECS[m.kind][0](value, settings, f"{where}.{m.suffix}")
    return members


def decode_member(suffix: str, data: bytes, where: str):
    """One member's bytes -> its value, by the member table (every reader decodes through here).

    `where` names the sample; unknown suffixes are errors.
    """
    m = MEMBER_BY_SUFFIX.get(suffix)
    if m is None:
        raise DatasetError(f"{where}: unknown member {suffix!r} (known: {MEMBER_ORDER})")
    return MEMBER_CODECS[m.kind][1](data, f"{where}.{suffix}")


def decode_sample(members: dict[str, bytes], where: str) -> dict:
    """{suffix: bytes} -> decoded-sample dict (per-hand fields always present, maybe empty).

    "meta" is present only when the json member is given; unknown suffixes are errors.
    """

    out: dict = {field: {} for field in PER_HAND_FIELDS}
    for suffix, data in members.items():
        value = decode_member(suffix, data, where)
        m = MEMBER_BY_SUFFIX[suffix]
        if m.hand is None:
            out[m.field] = value
        else:
            out[m.field][m.hand] = value
    return out


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
