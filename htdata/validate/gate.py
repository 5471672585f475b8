"""The quick validation as a gate: a command that hands a version on (publish) refuses one that fails it.

`require_valid` runs `validate_dataset` as `htdata validate DATASET --version N`
runs it by default (structure, a seeded 5% content sample plus each episode's
first frame, served maps, time, sensors; nothing is written into the dataset)
and raises `DatasetError` with the first failing check's first failure, in
the order of the report: one line naming what failed and where.
"""

from __future__ import annotations

import os

from htdata.errors import DatasetError
from htdata.validate.report import CHECKS
from htdata.validate.validator import validate_dataset


def first_failure(report: dict) -> str | None:
    """"CHECK: WHAT: MESSAGE" of a report's first failure (checks in report order), None when it passed."""
    for name in CHECKS:
        check = report["checks"].get(name, {})
        if check.get("failures"):
            f = check["failures"][0]
            more = check["failure_count"] - 1
            text = " ".join(f"{name} check, {f['what']}: {f['message']}".split())   # one line, whatever the message
            return text + (f" (and {more} more failure(s))" if more > 0 else "")
    return None


def require_valid(root: str | os.PathLike, version: int | None, doing: str = "published") -> None:
    """Raise DatasetError naming the first failing check when version `version` (None / 0: the only
    version of an unversioned dataset) fails the quick validation.

    Args:
        root: the local dataset folder.
        version: the version to check.
        doing: what the refused command would have done, for the message ("published").
    """
    version = version or None
    report = validate_dataset(root, version=version)
    failure = first_failure(report)
    if failure is not None or not report["ok"]:
        label = f"version {version}" if version else "the dataset"
        raise DatasetError(f"{root}: {label} fails `htdata validate`, not {doing}: {failure or 'see its report'}")
