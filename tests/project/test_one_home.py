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
