"""`htdata bench --quick`: every section present, finite numbers, every table rendered.

One quick run (module fixture, ~1 min on 2 shared cores) feeds all checks.
No timed assertions: the numbers only have to exist and be finite.
"""

import json
import math

import pytest

from htdata.bench import BenchConfig, finite_json
from htdata.benchmarks.report import HEADINGS, render_report
from htdata.cli import main as cli_main

SECTIONS = ("machine", "codecs", "rgb", "raster", "ingest", "rss", "loader", "index", "validate", "training")


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rc = cli_main(["bench", "--quick", "--quiet", "--out", str(out)])
    return rc, out


def numbers(obj, path="results"):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from numbers(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from numbers(v, f"{path}[{i}]")
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield path, obj


def test_quick_bench_writes_every_section_with_finite_numbers(quick_run):
    rc, out = quick_run
    results = json.loads((out / "results.json").read_text())
    assert results["errors"] == {}, results["errors"]
    assert rc == 0
    for section in SECTIONS:
        assert section in results, section
        found = list(numbers(results[section], section))
        assert found, f"section {section} holds no numbers"
        bad = [(p, v) for p, v in found if not math.isfinite(v)]
        assert not bad, bad
    assert (out / ".work").is_dir()


def test_quick_bench_content_is_consistent(quick_run):
    _, out = quick_run
    r = json.loads((out / "results.json").read_text())
    assert {row["codec"] for row in r["codecs"]["rows"]} == set(r["codecs"]["codecs"])
    assert {m["glove"] for m in r["codecs"]["margins"]} == {"opentouch", "touchanything"}
    lossless = [row for row in r["codecs"]["rows"] if row["codec"] in ("exr_float_zip",)]
    assert lossless[0]["max_error"] == 0.0
    assert {s["adapter"] for s in r["ingest"]["summary"]} == {"opentouch", "touchanything", "native"}
    for s in r["ingest"]["summary"]:
        assert s["frames"] > 0 and s["bound_frames_per_s"] > 0 and "scaling" in s
    assert [row["frames"] for row in r["rss"]] == list(BenchConfig.quick_config(out).rss_lengths)
    assert all(row["peak_rss_mb"] > 10 for row in r["rss"])
    assert {row["mode"] for row in r["raster"]} == {"nearest", "bilinear"}
    assert all(row["max_roundtrip_error"] == 0 for row in r["raster"] if row["mode"] == "nearest")
    assert [row["workers"] for row in r["validate"]] == [1, 2] and all(row["ok"] for row in r["validate"])
    assert [row["precision"] for row in r["training"]["rows"]] == ["fp32", "bf16 autocast"]
    assert r["loader"]["bound"]["samples_per_s"] > 0 and len(r["loader"]["rows"]) == 7
    assert r["machine"]["cpu_count"] >= 1 and r["machine"]["cpu_model"]


def test_report_has_every_table_heading(quick_run):
    _, out = quick_run
    report = (out / "REPORT.md").read_text()
    for heading in HEADINGS.values():
        assert heading in report, heading
    assert "**Default: exr_half_zip**" in report and "**Defaults: JPEG q95, cv2_area**" in report
    assert "Not measured" not in report
    assert report.count("|---|") >= 10


def test_report_names_failed_sections():
    results = {"command": "htdata bench", "quick": True, "seconds": 1.0, "created": "now",
               "errors": {"training": "RuntimeError: boom"}}
    text = render_report(results)
    assert "Not measured: RuntimeError: boom" in text
    assert all(h in text for h in HEADINGS.values())


def test_finite_json_replaces_non_finite():
    import numpy as np

    assert finite_json({"a": float("nan"), "b": [np.float32(1.5), np.int64(3), float("inf")], "c": True}) == \
        {"a": None, "b": [1.5, 3, None], "c": True}


@pytest.mark.parametrize("change, match", [
    ({"rss_lengths": (40, 20)}, "rss_lengths"),
    ({"train_steps": 0}, "train_steps"),
    ({"ingest_workers": ()}, "ingest_workers"),
    ({"scale": "huge"}, "scale"),
])
def test_bench_config_rejects_bad_sizes(tmp_path, change, match):
    cfg = BenchConfig.quick_config(tmp_path)
    for k, v in change.items():
        setattr(cfg, k, v)
    with pytest.raises(ValueError, match=match):
        cfg.validate()


def test_unknown_section_is_refused(tmp_path, capsys):
    assert cli_main(["bench", "--quick", "--out", str(tmp_path), "--only", "nope"]) == 2
    assert "unknown section" in capsys.readouterr().err
