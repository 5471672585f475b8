"""Facts and primitives with one home: a second copy is refused here, not found by the next review."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_create_exclusively_is_written_once():
    """'temp, fsync, link, fail if it exists' lives in htdata/fileio.py (link_exclusive, write_bytes_exclusive);
    the shard writer, the version files and the writer lock call it."""
    pattern = re.compile(r"\bos\.link\(")
    # merge hard-links another dataset's finished shard to share its bytes (a copy where links fail): not a create
    # and the HT-Bench-size bench hard-links a unit's shards to copy the unit without its bytes
    other_uses = {"htdata/fileio.py", "htdata/curate/merge.py", "htdata/benchmarks/htbenchsize.py"}
    found = [str(p.relative_to(ROOT)) for p in (ROOT / "htdata").rglob("*.py") if pattern.search(p.read_text())]
    assert sorted(set(found) - other_uses) == [], f"os.link outside htdata/fileio.py: {found}"


REPACK_CALL = re.compile(r"\.repack\(")                                   # nv.repack(reader, kept, ...)
WHOLE_EPISODE = re.compile(r"range\(int\([^)]*num_frames")              # KeptEpisode(e, range(int(e["num_frames"])))


def walks_of_its_own(text: str) -> list[str]:
    """Lines of a module outside htdata/write that re-pack parts or list an episode's every frame themselves."""
    return [line.strip() for line in text.splitlines() if REPACK_CALL.search(line) or WHOLE_EPISODE.search(line)]


def test_the_walk_patterns_catch_a_writer_of_its_own():
    planted = """
    for part in nv.parent.parts():
        kept = [KeptEpisode(e, range(int(e["num_frames"]))) for e in part.episodes]
        parts.append(nv.repack(nv.reader(), kept, samples_per_shard_of(part)))
"""
    assert len(walks_of_its_own(planted)) == 2
    assert not walks_of_its_own("parts = nv.carry_or_repack(lambda part: [KeptEpisode.whole(r) for r in part.episodes])")


def test_the_parents_parts_are_walked_by_newversion_only():
    """`NewVersion.carry_or_repack` is the one walk that carries or re-packs a version's parts and
    `KeptEpisode.whole` the one "every frame of an episode" (issue 48: four writers looped over their parent's
    parts themselves, and wrote the whole-episode range three times)."""
    found = {str(p.relative_to(ROOT)): hits for p in sorted((ROOT / "htdata").rglob("*.py"))
             if (ROOT / "htdata" / "write") not in p.parents and (hits := walks_of_its_own(p.read_text()))}
    assert not found, f"use NewVersion.carry_or_repack and KeptEpisode.whole (htdata/write): {found}"
