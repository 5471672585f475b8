"""What a streaming reader does with a sample it cannot read: `on_error=` (webdataset's handler idea).

- "raise" (default): the error goes up as it is (a DatasetError naming the sample, a shard file's OSError).
- "warn": the sample is skipped with one warning line naming it (logger "htdata.read"), the stream goes on.
- "skip": the sample is skipped without a word.

A shard file that does not open (missing, unreadable) is every sample in it: skipped whole, one line
naming the shard. Only a damaged or missing file is skipped (`READ_ERRORS`: DatasetError, OSError); a
version `htdata gc` removed (VersionCollected) and a programming error always raise. Streaming readers
take it: `DatasetReader.iter_samples`, `TactileStream` (through its ItemOptions). A map-style dataset owes
an item at every index, so it only raises.
"""

from __future__ import annotations

import logging

from htdata.errors import ArgumentError, DatasetError
from htdata.store.gcrecord import VersionCollected

ON_ERROR = ("raise", "warn", "skip")
READ_ERRORS = (DatasetError, OSError)   # a damaged or missing file: what a stream may skip
LOG = logging.getLogger("htdata.read")


def check_on_error(on_error: str) -> str:
    """`on_error`, or ArgumentError unless one of ON_ERROR."""
    if on_error not in ON_ERROR:
        raise ArgumentError(f"on_error must be one of {ON_ERROR}, got {on_error!r}")
    return on_error


class SkipPolicy:
    """One stream's `on_error`: in an `except READ_ERRORS as exc:` block, `if not policy.skips(exc, what): raise`.

    Args:
        on_error: "raise", "warn" or "skip".
    """

    def __init__(self, on_error: str = "raise"):
        self.on_error = check_on_error(on_error)
        self.skipped = 0      # samples (or shards) this stream skipped

    def skips(self, exc: BaseException, what: str) -> bool:
        """True when `exc` (met reading `what`: a sample or a shard) is skipped, after its warning line if
        "warn"; False when the caller must raise it."""
        if self.on_error == "raise" or isinstance(exc, VersionCollected) or not isinstance(exc, READ_ERRORS):
            return False
        self.skipped += 1
        if self.on_error == "warn":
            LOG.warning("htdata: skipped %s: %s", what, exc)
        return True
