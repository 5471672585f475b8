"""Where a command's output goes: the one rule for every command that writes a file or folder.

A missing folder above the output is created, and the command says so on
stderr (`htdata preview: created folder /data/new for /data/new/p.png`), so a
typo in a path never makes folders silently. A path whose folder is a file
is refused with one line. Commands call `output_path` once the inputs are
known to be good and before they write.
"""

from __future__ import annotations

import sys
from pathlib import Path

from htdata.errors import HtdataError


class OutputFolderError(HtdataError, NotADirectoryError):
    """An output whose folder cannot be made (a file stands in its way); one line naming it."""


def output_path(path, command: str) -> Path:
    """`path` with its missing parent folders created (announced on stderr); returns it as a Path."""
    path = Path(path)
    parent = path.parent
    first_missing = None
    probe = parent
    while not probe.exists():
        first_missing = probe
        if probe.parent == probe:
            break
        probe = probe.parent
    if first_missing is None:
        if not parent.is_dir():
            raise OutputFolderError(f"{path}: {parent} is a file, not a folder")
        return path
    if probe.exists() and not probe.is_dir():
        raise OutputFolderError(f"{path}: {probe} is a file, not a folder")
    parent.mkdir(parents=True, exist_ok=True)
    print(f"htdata {command}: created folder {first_missing} for {path}", file=sys.stderr)
    return path
