"""A dataset version on the command line: `3` or `v3` (what `htdata log` prints) both mean version 3."""

from __future__ import annotations

import argparse
import re

from htdata.errors import ArgumentError


def parse_version(text: str) -> int:
    """'3' or 'v3' -> 3; anything else is an ArgumentError naming the text."""
    m = re.fullmatch(r"[vV]?(\d+)", str(text).strip())
    if m is None:
        raise ArgumentError(f"not a version: {text!r} (write 3 or v3; `htdata log DATASET` lists them)")
    return int(m.group(1))


def version_arg(text: str) -> int:
    """argparse `type=` for a version: the error is argparse's one line."""
    try:
        return parse_version(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
