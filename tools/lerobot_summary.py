"""`make lerobot-check`'s short verdict: lerobot-doctor's checks and tools/lerobot_check.py's comparison.

    python tools/lerobot_summary.py DOCTOR.md CHECK.json [--expected-fail "CHECK=why"]...
        [--expected-fail-messages "CHECK=REGEX=why"]... [--full FILE]...

lerobot-doctor prints one line per flagged dimension (about 1,500 lines on the sample export:
every constant taxel cell is a warning), so `make lerobot-check` keeps its full report in files
and prints this instead: one line per doctor check (its verdict and how many messages it has),
the rows / episodes / windows tools/lerobot_check.py compared and the RGB difference it measured,
and where the full reports are. Reads the doctor's Markdown report (`--markdown`), whose "Checks"
table is `| Check | **SEVERITY** | message<br>message... |`. Stdlib only.

Exit 0 when the doctor reports no FAIL but the expected ones (`--expected-fail`, e.g. the
Training Readiness FAIL of every dataset without an `action` feature) and lerobot_check.py found
no problem; 1 otherwise (also when a report is missing: the step that writes it failed).
`--expected-fail-messages` is narrower: the check's FAIL is expected only when every failing
message in it (lerobot-doctor's failing messages end in "detected": clipping, NaN, Inf) matches
REGEX, e.g. the padding slots of `--tactile-window` features, 0 in most frames, which the doctor
(reading every column as an action when there is no `action` feature) calls clipped.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

_ROW = re.compile(r"^\|\s*(?P<check>[^|]+?)\s*\|\s*\*\*(?P<severity>[A-Z]+)\*\*\s*\|\s*(?P<messages>.*)\|\s*$")


def parse_doctor(markdown: str) -> tuple[dict[str, str], list[tuple[str, str, list[str]]]]:
    """(header fields, [(check, severity, messages)]) of lerobot-doctor's Markdown report."""
    header = dict(re.findall(r"^- \*\*(\w[\w ]*):\*\* (.+)$", markdown, flags=re.M))
    checks = []
    in_table = False
    for line in markdown.splitlines():
        if line.startswith("## "):
            in_table = line.strip() == "## Checks"
            continue
        m = _ROW.match(line) if in_table else None
        if m:
            text = m["messages"].strip()
            messages = [] if text in ("", "_clean_") else [t.removeprefix("- ").strip() for t in text.split("<br>")]
            checks.append((m["check"], m["severity"], messages))
    return header, checks


def failing_messages_match(messages: list[str], pattern: str) -> bool:
    """Every failing message (ending in "detected") matches `pattern`, and there is at least one."""
    failing = [m for m in messages if m.endswith("detected")]
    return bool(failing) and all(re.search(pattern, m) for m in failing)


def summarise(doctor_md: Path, check_json: Path, expected_fail: dict[str, str],
              full: list[str], expected_messages: dict[str, tuple[str, str]] | None = None) -> tuple[list[str], bool]:
    """(lines to print, ok)."""
    lines, ok = [], True
    if not doctor_md.is_file():
        return [f"lerobot-check: FAILED: no doctor report {doctor_md} (lerobot-doctor did not finish; "
                f"see {', '.join(full) or 'its output'})"], False
    header, checks = parse_doctor(doctor_md.read_text(encoding="utf-8"))
    if not checks:
        return [f"lerobot-check: FAILED: {doctor_md} holds no Checks table (not a lerobot-doctor report?)"], False
    lines.append(f"lerobot-doctor {header.get('Version', '?')} on {header.get('Dataset', '?').strip('`')}: "
                 f"{header.get('Episodes', '?')} episodes, {header.get('Frames', '?')} frames")
    for name, severity, messages in checks:
        count = len(messages)
        note = f"  ({count} message{'s' if count != 1 else ''})" if count else ""
        narrow = (expected_messages or {}).get(name)
        if severity == "FAIL" and name in expected_fail:
            note += f"  expected: {expected_fail[name]}"
        elif severity == "FAIL" and narrow and failing_messages_match(messages, narrow[0]):
            note += f"  expected: {narrow[1]}"
        elif severity == "FAIL":
            ok = False
        lines.append(f"  {severity:<4}  {name}{note}")
    if not check_json.is_file():
        lines.append(f"tools/lerobot_check.py: FAILED: no {check_json} (it did not finish; see "
                     f"{', '.join(full) or 'its output'})")
        return lines, False
    result = json.loads(check_json.read_text(encoding="utf-8"))
    problems = result.get("problems", [])
    ok = ok and not problems
    rgb = result.get("rgb_vs_htdata", {})
    rgb_text = (f"mean |diff| {rgb['mean_abs']}, p99 {rgb['p99_abs']:g}, max {rgb['max_abs']} of 255 "
                f"over {rgb['frames']} frames" if {"mean_abs", "p99_abs", "max_abs", "frames"} <= set(rgb)
                else json.dumps(rgb))
    lines.append(f"tools/lerobot_check.py: {'OK' if not problems else f'{len(problems)} problem(s)'}: "
                 f"{result.get('rows', '?')} rows and {result.get('episodes', '?')} episodes compared with "
                 f"htdata's reader, {result.get('windows_checked', '?')} delta_timestamps windows, "
                 f"{result.get('tactile_window_rows_checked', 0)} full-rate glove rows in tactile windows; "
                 f"RGB vs htdata: {rgb_text}")
    lines += [f"  FAIL {p}" for p in problems[:5]]
    if full:
        lines.append(f"full reports: {', '.join(full)}")
    lines.append(f"lerobot-check: {'OK' if ok else 'FAILED'}")
    return lines, ok


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("doctor_md", type=Path, help="lerobot-doctor check --markdown FILE")
    p.add_argument("check_json", type=Path, help="tools/lerobot_check.py --json FILE")
    p.add_argument("--expected-fail", action="append", default=[], metavar="CHECK=WHY",
                   help="a doctor check whose FAIL is expected, and why (repeatable)")
    p.add_argument("--expected-fail-messages", action="append", default=[], metavar="CHECK=REGEX=WHY",
                   help="a doctor check whose FAIL is expected when every failing message matches REGEX (repeatable)")
    p.add_argument("--full", action="append", default=[], metavar="FILE",
                   help="a file holding a full report, named in the summary (repeatable)")
    args = p.parse_args(argv)
    expected = dict(item.split("=", 1) for item in args.expected_fail)
    narrow = {}
    for item in args.expected_fail_messages:
        name, pattern, why = item.split("=", 2)
        narrow[name] = (pattern, why)
    lines, ok = summarise(args.doctor_md, args.check_json, expected, args.full, narrow)
    print("\n".join(lines))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
