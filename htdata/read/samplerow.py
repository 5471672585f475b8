"""Where a sample lies in its shard: its index row as plain ints (`SampleRow`) and its members' spans.

One seek + one read returns a sample's bytes (htdata/read/reader.py): the row gives the shard and the
offset of its first tar header, `member_layout` where each member wanted lies after it.
"""

from __future__ import annotations

from typing import NamedTuple

from htdata.format.shardio import BLOCK, padded
from htdata.format.table import MEMBER_ORDER


class SampleRow(NamedTuple):
    """One index.npy row as plain ints; `sizes` follows format.MEMBER_ORDER (0 = absent).

    Args:
        shard: the shard's number (position in the manifest's "shards").
        offset: byte offset of the sample's first tar header in that shard.
        episode: the episode's position in episodes.jsonl.
        frame: the frame within the episode.
        sizes: each member's size in bytes, in MEMBER_ORDER (0: the sample lacks it).
    """
    shard: int
    offset: int
    episode: int
    frame: int
    sizes: tuple[int, ...]


def member_layout(sizes: tuple[int, ...], wanted=None) -> tuple[list[tuple[str, int, int]], int]:
    """Where a sample's members lie in its span of the shard, and how many bytes to read.

    Only members present (size > 0) and in `wanted` are listed; the read
    stops at the end of the last listed member.

    Args:
        sizes: member sizes in MEMBER_ORDER (SampleRow.sizes).
        wanted: suffixes to list ("json", "rgb.jpg", ...); None lists every present member.

    Returns:
        ([(suffix, header offset from the first header, size)], bytes to read).
    """
    layout, pos, end = [], 0, 0
    for suffix, size in zip(MEMBER_ORDER, sizes):
        if size:
            if wanted is None or suffix in wanted:
                layout.append((suffix, pos, size))
                end = pos + BLOCK + size
            pos += BLOCK + padded(size)
    return layout, end
