"""Each glove rule has one owner (issue 48): direction and "a raw-count glove" are htdata/glove/glovevalue.py's.

A module that restates them (tests a convention string, or full scale > 1, itself) drifts from the owner: an
inverted glove then reads as direct in one rule and not another (issue 43).
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OWNER = ROOT / "htdata" / "glove" / "glovevalue.py"
RESTATED = (re.compile(r"""[!=]=\s*["'](inverted|direct)["']"""),            # convention == "inverted"
            re.compile(r"""["'](inverted|direct)["']\s*[!=]="""),
            re.compile(r"""(max|max_value)["'][^)\n]*\)\)?\s*>\s*1(\.0)?\b"""))     # float(value["max"]) > 1


def restatements(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if any(p.search(line) for p in RESTATED)]


def test_the_patterns_catch_a_restated_rule():
    assert restatements('    if value["convention"] == "inverted":\n')
    assert restatements('raw = cal.get("convention") == "direct" and float(cal.get("max_value", 1.0)) > 1.0\n')
    assert restatements('extra = X if float(value["max"]) > 1 else {}\n')
    assert not restatements('if is_raw_count(value["max"]):\n')


def test_no_module_restates_a_glove_rule_outside_its_owner():
    found = {str(p.relative_to(ROOT)): hits for p in sorted((ROOT / "htdata").rglob("*.py"))
             if p != OWNER and (hits := restatements(p.read_text()))}
    assert not found, f"use htdata.glove.glovevalue (is_inverted, is_raw_count, toward_pressure): {found}"


TRUTH_OWNER = ROOT / "htdata" / "synthetic" / "rawfacts.py"
TRUTH_NAMES = ("PRESSED", "QUIET", "TRUTH_PERCENTILE", "CONTACT_CELLS", "REST_SHARE", "START_FRAMES", "MID_GRASP",
               "MID_GRASP_GAIN")


def test_the_real_glove_truth_has_one_home():
    """The real-glove measures' truth constants (15 counts, 7 cells, 10 %, ...) are rawfacts.py's; the
    bench's versions 1 and 2 import them (they sat in three modules, issue 48). Only the measuring side is
    searched: a toolkit rule (glove/activity.py's REST_SHARE) is the rule measured, never the truth."""
    defines = re.compile(rf"^({'|'.join(TRUTH_NAMES)})\s*=", re.MULTILINE)
    assert len(defines.findall(TRUTH_OWNER.read_text())) == len(TRUTH_NAMES)
    found = {str(p.relative_to(ROOT)): defines.findall(p.read_text()) for p in sorted(
             [*(ROOT / "htdata" / "benchmarks").rglob("*.py"), *(ROOT / "htdata" / "synthetic").rglob("*.py")])
             if p != TRUTH_OWNER and defines.search(p.read_text())}
    assert not found, f"import them from htdata.synthetic.rawfacts: {found}"
