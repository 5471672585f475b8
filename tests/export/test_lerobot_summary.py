"""tools/lerobot_summary.py: `make lerobot-check`'s short verdict from lerobot-doctor's Markdown report."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("lerobot_summary", ROOT / "tools/lerobot_summary.py")
summary = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(summary)

# lerobot-doctor 0.2.0's report on the sample export, cut to a few messages per check (the real
# one lists every flagged taxel dimension; its text and layout are as the doctor writes them)
DOCTOR_MD = """# lerobot-doctor report

- **Version:** 0.2.0
- **Dataset:** `data/lerobot`
- **Codebase:** v3.0
- **Episodes:** 46
- **Frames:** 2,982
- **FPS:** 30
- **Overall:** **FAIL**

**Summary:** 5 PASS | 5 WARN | 1 FAIL

## Checks

| Check | Severity | Messages |
| --- | --- | --- |
| Metadata & Format Compliance | **PASS** | _clean_ |
| Temporal Consistency | **PASS** | _clean_ |
| Action Quality | **WARN** | - observation.tactile.left.raw[43]: 53.9% of values at minimum (0.0000)<br>- observation.tactile.left.raw[44]: 53.9% of values at minimum (0.0000)<br>- observation.tactile.left.raw[45]: 53.9% of values at minimum (0.0000) |
| Video Integrity | **PASS** | _clean_ |
| Episode Health | **WARN** | - 6/46 episodes shorter than chunk_size=50 (used by ACT/Diffusion policies) |
| Training Readiness | **FAIL** | - No action features found -- cannot train any policy |
| Anomaly Detection | **WARN** | - observation.present: 1 constant dimension(s) across ALL episodes: dim 0 (=1.0000) -- possible stuck sensor |
| Portability | **PASS** | _clean_ |

## Suggested fixes

### Drop zero-variance features from training inputs
"""

CHECK = {"problems": [], "rows": 2982, "episodes": 46, "windows_checked": 20,
         "rgb_vs_htdata": {"frames": 2982, "mean_abs": 2.06, "p99_abs": 14.0, "max_abs": 94}}
EXPECTED = {"Training Readiness": "no action feature"}


def _write(tmp_path, md=DOCTOR_MD, check=CHECK):
    (tmp_path / "doctor.md").write_text(md)
    (tmp_path / "check.json").write_text(json.dumps(check))
    return tmp_path / "doctor.md", tmp_path / "check.json"


def test_summary_is_one_line_per_check_with_rows_and_rgb(tmp_path):
    md, js = _write(tmp_path)
    lines, ok = summary.summarise(md, js, EXPECTED, ["data/lerobot_doctor.md"])
    assert ok and len(lines) == 1 + 8 + 1 + 1 + 1
    assert lines[0] == "lerobot-doctor 0.2.0 on data/lerobot: 46 episodes, 2,982 frames"
    assert "  WARN  Action Quality  (3 messages)" in lines
    assert "  PASS  Metadata & Format Compliance" in lines
    assert "  FAIL  Training Readiness  (1 message)  expected: no action feature" in lines
    assert lines[-3] == ("tools/lerobot_check.py: OK: 2982 rows and 46 episodes compared with htdata's reader, "
                         "20 delta_timestamps windows, 0 full-rate glove rows in tactile windows; RGB vs htdata: mean |diff| 2.06, p99 14, max 94 of 255 "
                         "over 2982 frames")
    assert lines[-2] == "full reports: data/lerobot_doctor.md" and lines[-1] == "lerobot-check: OK"


def test_an_unexpected_fail_or_a_problem_or_a_missing_report_fails(tmp_path):
    md, js = _write(tmp_path)
    lines, ok = summary.summarise(md, js, {}, [])              # the training FAIL not declared expected
    assert not ok and lines[-1] == "lerobot-check: FAILED"
    md, js = _write(tmp_path, check={**CHECK, "problems": ["episode 3 frame 4: raw differs"]})
    lines, ok = summary.summarise(md, js, EXPECTED, [])
    assert not ok and "  FAIL episode 3 frame 4: raw differs" in lines and "1 problem(s)" in lines[-3]
    js.unlink()
    lines, ok = summary.summarise(md, js, EXPECTED, ["data/lerobot_check.txt"])
    assert not ok and "no " + str(js) in lines[-1] and "data/lerobot_check.txt" in lines[-1]
    md.unlink()
    [line], ok = summary.summarise(md, js, EXPECTED, [])
    assert not ok and line.startswith("lerobot-check: FAILED: no doctor report")


def test_the_command_prints_the_summary_and_exits_with_the_verdict(tmp_path, capsys):
    md, js = _write(tmp_path)
    assert summary.main([str(md), str(js), "--expected-fail", "Training Readiness=no action feature"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 11
    assert summary.main([str(md), str(js)]) == 1


def test_a_narrow_expected_fail_accepts_only_the_window_padding(tmp_path):
    pattern = r"^observation\.tactile\.\w+\.window\w*\[\d+\]: .* -- clipping detected$"
    narrow = {"Action Quality": (pattern, "window padding")}
    padding = ("| Action Quality | **FAIL** | - observation.tactile.left.raw[43]: 53.9% of values at minimum (0.0000)"
               "<br>- observation.tactile.left.window[700]: 99.6% of values at minimum (0.0000) -- clipping detected |")
    md, js = _write(tmp_path, DOCTOR_MD.replace(DOCTOR_MD.splitlines()[15], padding))
    lines, ok = summary.summarise(md, js, EXPECTED, [], narrow)
    assert ok and any("expected: window padding" in line for line in lines), lines
    # a real clipping of a .raw feature, or a NaN, is not padding: the FAIL stands
    for other in ("observation.tactile.left.raw[3]: 99.9% of values at maximum (1023.0000) -- clipping detected",
                  "observation.tactile.left.window: 4 NaN values detected"):
        md, js = _write(tmp_path, DOCTOR_MD.replace(DOCTOR_MD.splitlines()[15], padding[:-2] + f"<br>- {other} |"))
        assert not summary.summarise(md, js, EXPECTED, [], narrow)[1], other
