"""What `htdata gc` leaves behind for the readers it may outlive: one tombstone per collected version.

gc writes `versions/vN.collected.json` (when, which command, the retention
window it applied) BEFORE it deletes anything of version N. A reader that
still has version N open, or opens it later, and finds one of its files gone
raises `VersionCollected`, naming the version and that gc, instead of a bare
FileNotFoundError. Tombstones are a few hundred bytes and are never deleted.
"""

from __future__ import annotations

import json
import os

from htdata.errors import HtdataError
from htdata.store import storage

VERSIONS_DIR = "versions"


class VersionCollected(HtdataError, FileNotFoundError):
    """A file of a version `htdata gc` removed; the message names the version and the gc."""

    def __init__(self, version: int, record: dict, where: str):
        self.version = version
        self.record = record
        super().__init__(
            f"{where}: version {version} was removed by `{record.get('command', 'htdata gc')}` at "
            f"{record.get('time', '?')} (retention {record.get('retention', '?')}); open a newer version "
            f"(htdata log lists them)")


def tombstone_file(version: int) -> str:
    return f"{VERSIONS_DIR}/v{version:06d}.collected.json"


def read_tombstone(root: str | os.PathLike, version: int) -> dict | None:
    path = storage.join(root, tombstone_file(version))
    try:
        if not storage.exists(path):
            return None
        return json.loads(storage.read_text(path))
    except (OSError, ValueError):
        return {"command": "htdata gc", "time": "?", "retention": "?"}   # damaged: still a gc's mark


def collected_error(root: str | os.PathLike, version: int | None, where: str | None = None) -> VersionCollected | None:
    """VersionCollected for `version` when a gc removed it, else None (then the loss has another cause)."""
    if version is None:
        return None
    record = read_tombstone(root, version)
    return None if record is None else VersionCollected(version, record, where or os.fspath(root))
