"""The validation report: one `Check` per section, the worker-side `Recorder`, and its text form.

A report is plain JSON (`validate_dataset` returns it, `write_report` stores
it): {"dataset", "created", "params", "checks": {section: Check.to_dict()},
"stats", "ok", "elapsed_s", "samples"}. Failures and warnings are listed up to
`max_listed` per check; every one is counted.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from htdata.fileio import write_json_atomic

CHECKS = ("structure", "content", "time", "sensors", "splits")
TEXT_FAILURES = 10     # failures / warnings per check shown by format_report (the JSON has them all)
TEXT_WARNINGS = 3


class Check:
    """Failures and warnings of one named check; listing is capped, counting is not.

    Args:
        name: the check's name (one of CHECKS).
        max_listed: failures and warnings listed at most (all are counted).
    """

    def __init__(self, name: str, max_listed: int):
        self.name = name
        self.max_listed = max_listed
        self.checked: Counter = Counter()
        self.failures: list[dict] = []
        self.failure_counts: Counter = Counter()
        self.warnings: list[dict] = []
        self.warning_counts: Counter = Counter()
        self.skipped: list[str] = []

    def fail(self, what: str, message: str, **where) -> None:
        self.failure_counts[what] += 1
        if len(self.failures) < self.max_listed:
            self.failures.append({"what": what, "message": message, **where})

    def warn(self, what: str, message: str, **where) -> None:
        self.warning_counts[what] += 1
        if len(self.warnings) < self.max_listed:
            self.warnings.append({"what": what, "message": message, **where})

    def merge(self, records: dict) -> None:
        """Add failures/warnings/checked produced by a worker."""
        for rec in records.get("failures", []):
            self.fail(**rec)
        for rec in records.get("warnings", []):
            self.warn(**rec)
        self.checked.update(records.get("checked", {}))

    @property
    def ok(self) -> bool:
        return not self.failure_counts

    def to_dict(self) -> dict:
        return {
            "status": "skipped" if self.skipped and not self.checked and self.ok else
                      ("pass" if self.ok else "fail"),
            "checked": dict(self.checked),
            "failure_count": int(sum(self.failure_counts.values())),
            "failure_counts": dict(self.failure_counts),
            "warning_count": int(sum(self.warning_counts.values())),
            "warning_counts": dict(self.warning_counts),
            "failures": self.failures,
            "warnings": self.warnings,
            "skipped": self.skipped,
        }


class Recorder:
    """Worker-side stand-in for Check: plain lists, merged by the parent."""

    def __init__(self):
        self.failures: list[dict] = []
        self.warnings: list[dict] = []
        self.checked: Counter = Counter()

    def fail(self, what: str, message: str, **where) -> None:
        self.failures.append({"what": what, "message": message, **where})

    def warn(self, what: str, message: str, **where) -> None:
        self.warnings.append({"what": what, "message": message, **where})

    def to_dict(self) -> dict:
        return {"failures": self.failures, "warnings": self.warnings, "checked": dict(self.checked)}


def format_report(report: dict) -> str:
    """The report as the text `htdata validate` prints: one line per check, then its first findings."""
    lines = [f"htdata validate {report['dataset']}: {report['samples']} samples, "
             f"{'deep' if report['params']['deep'] else 'sampled'} content check"]
    for name, c in report["checks"].items():
        checked = ", ".join(f"{v} {k}" for k, v in c["checked"].items()) or "-"
        lines.append(f"  {name:<9} {c['status'].upper():<7} {c['failure_count']} failure(s), "
                     f"{c['warning_count']} warning(s)  [{checked}]")
        for f in c["failures"][:TEXT_FAILURES]:
            lines.append(f"      FAIL {f['what']}: {f['message']}")
        if c["failure_count"] > TEXT_FAILURES:
            lines.append(f"      ... {c['failure_count'] - TEXT_FAILURES} more failure(s) in the JSON report")
        for w in c["warnings"][:TEXT_WARNINGS]:
            lines.append(f"      warn {w['what']}: {w['message']}")
        if c["warning_count"] > TEXT_WARNINGS:
            lines.append(f"      ... {c['warning_count'] - TEXT_WARNINGS} more warning(s) in the JSON report")
        for s in c["skipped"][:3]:
            lines.append(f"      skipped: {s}")
    lines.append("OK: dataset is sound" if report["ok"] else "FAILED: see failures above")
    return "\n".join(lines)


def write_report(report: dict, path: Path) -> None:
    """Write `report` (validate_dataset's) as JSON at `path`, atomically (temp + rename)."""
    write_json_atomic(path, report)
