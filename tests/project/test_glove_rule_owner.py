"""Each glove rule has one owner (issue 48): direction and "a raw-count glove" are htdata/glove/glovevalue.py's,
"the normaliser takes a rest off" (and a calibration record read as a config) htdata/glove/normaliseconfig.py's.

A module that restates them (tests a convention string, or full scale > 1, itself) drifts from the owner: an
inverted glove then reads as direct in one rule and not another (issue 43). The modules that read manifest
records (validate/, inspect/, curate/, ...) ask `NormaliseConfig.from_record(entry)` instead of the entry's keys.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OWNER = ROOT / "htdata" / "glove" / "glovevalue.py"
RESTATED = (re.compile(r"""[!=]=\s*["'](inverted|direct)["']"""),            # convention == "inverted"
            re.compile(r"""["'](inverted|direct)["']\s*[!=]="""),
            re.compile(r"""(max|max_value)["'][^)\n]*\)\)?\s*>\s*1(\.0)?\b"""),     # float(value["max"]) > 1
            re.compile(r"""\b(top|full_scale|max_value|raw_max)\s*>\s*1(\.0)?\b"""))    # top > 1.0 (inspect's view)


def restatements(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if any(p.search(line) for p in RESTATED)]


def test_the_patterns_catch_a_restated_rule():
    assert restatements('    if value["convention"] == "inverted":\n')
    assert restatements('raw = cal.get("convention") == "direct" and float(cal.get("max_value", 1.0)) > 1.0\n')
    assert restatements('extra = X if float(value["max"]) > 1 else {}\n')
    assert restatements('        if top > 1.0 and stored(raw_member(hand)):\n')
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


CONFIG_OWNER = ROOT / "htdata" / "glove" / "normaliseconfig.py"
HAS_REST = re.compile(r"""["']none["']\s*or\b.*taxel_calibration""")    # baseline != "none" or ...sha256
RECORD_READERS = ("validate", "inspect", "curate", "export", "read", "commands", "store", "write")
RECORD_KEYS = re.compile(r"""\.get\(["'](convention|max_value|baseline|taxel_calibration_sha256|noise_k|noise_floor)["']"""
                         r"""|\[["'](max_value|baseline|taxel_calibration_sha256|noise_k|noise_floor)["']\]""")


def config_rules_restated(text: str, reads_records: bool) -> list[str]:
    """Lines that restate "the normaliser takes a rest off", or (in a module reading manifest records) read a
    calibration record's rule keys themselves."""
    return [line.strip() for line in text.splitlines()
            if HAS_REST.search(line) or (reads_records and RECORD_KEYS.search(line))]


def test_the_patterns_catch_a_restated_config_rule():
    planted = """
        raw_counts = is_raw_count(cal.get("max_value", 1.0))
        if not raw_counts or cal.get("baseline") != "none" or cal.get("taxel_calibration_sha256"):
            continue
        if cfg.baseline != "none" or cfg.taxel_calibration_sha256:
"""
    assert len(config_rules_restated(planted, reads_records=True)) == 3
    assert len(config_rules_restated(planted, reads_records=False)) == 2
    assert not config_rules_restated("cfg = NormaliseConfig.from_record(cal)\nif cfg.subtracts_rest:\n", True)


def test_no_module_restates_a_config_rule_outside_its_owner():
    found = {}
    for p in sorted((ROOT / "htdata").rglob("*.py")):
        reads_records = p.relative_to(ROOT / "htdata").parts[0] in RECORD_READERS
        if p != CONFIG_OWNER and (hits := config_rules_restated(p.read_text(), reads_records)):
            found[str(p.relative_to(ROOT))] = hits
    assert not found, f"use htdata.glove.normaliseconfig.NormaliseConfig (from_record, raw_counts, subtracts_rest): " \
                      f"{found}"
