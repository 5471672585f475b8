"""Facts and primitives with one home: a second copy is refused here, not found by the next review."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_create_exclusively_is_written_once():
    """'temp, fsync, link, fail if it exists' lives in htdata/fileio.py (link_exclusive, write_bytes_exclusive);
    the shard writer, the version files and the writer lock call it."""
    pattern = re.compile(r"\bos\.link\(")
    found = [str(p.relative_to(ROOT)) for p in (ROOT / "htdata").rglob("*.py")
             if p.name != "fileio.py" and pattern.search(p.read_text())]
    assert found == [], f"os.link outside htdata/fileio.py: {found}"
