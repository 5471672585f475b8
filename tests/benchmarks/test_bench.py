"""`htdata bench --quick`: every section present, finite numbers, every table rendered.

One quick run (module fixture, ~1 min on 2 shared cores) feeds all checks.
No timed assertions: the numbers only have to exist and be finite. The run
also sees a throwaway distribution on sys.path whose entry points (group
htdata.bench_sections) add a working section, a failing one and one named
like a built-in, so discovery, the context, REPORT.md rendering and error
isolation are exercised as an installed plugin would be.
"""

import importlib.util
import json
import math
import os
import sys
import textwrap

import pytest

from htdata.benchmarks.report import HEADINGS, render_report
from htdata.benchmarks.suite import BUILTIN_SECTIONS, BenchConfig, discover_sections, finite_json
from htdata.cli import main as cli_main
from htdata.ingest.executors import usable_cores

# `htdata view` needs the [view] extra (rerun-sdk): without it its section fails with that one line
NO_RERUN = {"view"} if importlib.util.find_spec("rerun") is None else set()
SECTIONS = tuple(s for s in ("machine",) + BUILTIN_SECTIONS if s not in NO_RERUN)
PLUGIN_MODULE = "htdata_bench_probe_plugin"
PLUGIN_CODE = """
    from htdata.store.manifest import load_manifest

    def probe(ctx):
        (ctx.work / "probe.txt").write_text("scratch")
        n = load_manifest(ctx.dataset)["counts"]["samples"]
        return {"samples": n, "quick": ctx.quick, "seed": ctx.seed, "work": str(ctx.work),
                "markdown": "| probe | samples |\\n|---|---|\\n| ok | %d |" % n}

    def broken(ctx):
        raise RuntimeError("probe plugin exploded")
"""
PLUGIN_ENTRY_POINTS = f"""
    [htdata.bench_sections]
    probe = {PLUGIN_MODULE}:probe
    zz_broken = {PLUGIN_MODULE}:broken
    codecs = {PLUGIN_MODULE}:probe
"""


def install_probe_plugin(folder):
    """A minimal installed distribution: a module plus its .dist-info with entry points."""
    (folder / f"{PLUGIN_MODULE}.py").write_text(textwrap.dedent(PLUGIN_CODE))
    dist = folder / "htdata_bench_probe-0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: htdata-bench-probe\nVersion: 0\n")
    (dist / "entry_points.txt").write_text(textwrap.dedent(PLUGIN_ENTRY_POINTS))


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    plugin_dir = tmp_path_factory.mktemp("plugin")
    install_probe_plugin(plugin_dir)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(plugin_dir))
        rc = cli_main(["bench", "--quick", "--quiet", "--out", str(out)])
        discovered = set(discover_sections())
    sys.modules.pop(PLUGIN_MODULE, None)
    return rc, out, discovered


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
    rc, out, _ = quick_run
    results = json.loads((out / "results.json").read_text())
    # Only the probe distribution's failing and misnamed sections fail; everything else ran.
    assert set(results["errors"]) == {"zz_broken", f"codecs ({PLUGIN_MODULE}:probe)"} | NO_RERUN, results["errors"]
    assert rc == 1
    for section in SECTIONS:
        assert section in results, section
        if section == "realglove":       # no --real-glove here: it says so (tests/glove/test_real_glove_rules.py)
            assert "--real-glove" in results[section]["skipped"]
            continue
        found = list(numbers(results[section], section))
        assert found, f"section {section} holds no numbers"
        bad = [(p, v) for p, v in found if not math.isfinite(v)]
        assert not bad, bad
    assert (out / ".work").is_dir()


def test_discovered_sections_run_after_builtins_with_context(quick_run):
    _, out, discovered = quick_run
    r = json.loads((out / "results.json").read_text())
    assert {"probe", "zz_broken", "codecs"} <= discovered
    assert r["plugins"]["probe"] == f"{PLUGIN_MODULE}:probe" and "codecs" not in r["plugins"]
    probe = r["probe"]
    assert probe["quick"] is True and probe["seed"] == 0
    assert probe["samples"] == r["loader"]["samples_in_dataset"] > 0      # ctx.dataset = the combined dataset
    assert (out / ".work" / "sections" / "probe" / "probe.txt").read_text() == "scratch"
    assert "zz_broken" not in r and "RuntimeError: probe plugin exploded" in r["errors"]["zz_broken"]
    assert r["codecs"]["default"] == "exr_float_zip"                      # the built-in section was not displaced
    order = list(r["timings_s"])
    assert order[:len(BUILTIN_SECTIONS)] == list(BUILTIN_SECTIONS)
    assert set(order[len(BUILTIN_SECTIONS):]) == set(r["plugins"])
    # Any other installed section (HandTouch's "training") ran cleanly too.
    for name in set(r["plugins"]) - {"probe", "zz_broken"}:
        assert name in r and name not in r["errors"], name


@pytest.mark.skipif(bool(NO_RERUN), reason="rerun-sdk is not installed (pip install '.[view]')")
def test_quick_bench_views_each_length_once(quick_run):
    _, out, _ = quick_run
    v = json.loads((out / "results.json").read_text())["view"]
    assert [(r["frames"], r["run"]) for r in v["rows"]] == [(20, "first"), (40, "first")]
    assert all(r["rrd_bytes"] > 0 and r["peak_rss_mb"] > 0 and r["cpu_s"] > 0 for r in v["rows"])
    assert "## htdata view --save" in (out / "REPORT.md").read_text()


def test_quick_bench_content_is_consistent(quick_run):
    _, out, _ = quick_run
    r = json.loads((out / "results.json").read_text())
    assert {row["codec"] for row in r["codecs"]["rows"]} == set(r["codecs"]["codecs"])
    assert {m["layout"] for m in r["codecs"]["margins"]} == {
        "opentouch_right_16x16", "touchanything_left_21x21", "touchanything_right_21x21"}
    steps = {m["layout"]: m["step"] for m in r["codecs"]["margins"]}
    assert steps["opentouch_right_16x16"] == 1 / 3072 and steps["touchanything_left_21x21"] == 1 / 255
    lossless = [row for row in r["codecs"]["rows"] if row["codec"] in ("exr_float_zip",)]
    assert lossless[0]["max_error"] == 0.0
    assert {s["adapter"] for s in r["ingest"]["summary"]} == {"opentouch", "touchanything", "native"}
    for s in r["ingest"]["summary"]:
        assert s["frames"] > 0 and s["bound_frames_per_s"] > 0 and len(s["overhead_pct_reps"]) == s["reps"] == 1
        assert s["overhead_pct"] == pytest.approx(100 * (1 - s["ratio_to_bound"]))
    assert "revision" not in r["ingest"]            # quick runs skip the revision rows
    # the default stores maps; the comparison row is the maps = "raw" opt-in
    assert {s["adapter"] for s in r["ingest"]["maps_raw"]["summary"]} == {"opentouch", "touchanything", "native"}
    glove = r["maps"]["glove_only"]
    assert glove["frames"] > 0 and glove["bytes_per_frame_stored"] > glove["bytes_per_frame_raw"] > 0
    assert glove["speed_ratio"] == pytest.approx(glove["frames_per_s_stored"] / glove["frames_per_s_raw"])
    assert glove["cpu_s_stored"] > 0 and glove["cpu_s_raw"] > 0
    assert glove["costs"]["maps"] > 0 and 0 < glove["projections"]["ceiling_one_core"] <= 1
    assert "skipped" in r["maps"]["glove_only_real"]     # no --real-glove DIR: not measured, and said
    scaling = r["scaling"]
    cores = max(2, usable_cores())                  # 1 -> N workers on the machine's cores
    assert {s["adapter"] for s in scaling["summary"]} == {"opentouch", "touchanything", "native"}
    for s in scaling["summary"]:
        assert (s["workers_lo"], s["workers_hi"]) == (1, cores) and s["scaling"] > 0 and s["fixed_s_hi"] > 0
    driver = r["driver"]                            # quick: opentouch, tiny vs small corpus
    (d,) = driver["summary"]
    assert d["adapter"] == "opentouch" and (d["small"]["scale"], d["big"]["scale"]) == ("tiny", "small")
    assert d["big"]["frames"] > d["small"]["frames"] > 0 and d["workers"] == cores
    # the slope of the serial seconds without the pooled glove rest (bounded: in the fixed seconds)
    assert d["serial_growth_s_per_frame"] == pytest.approx(
        (d["big"]["unbounded_s"] - d["small"]["unbounded_s"]) / (d["big"]["frames"] - d["small"]["frames"]))
    assert all(0 <= d[k]["unbounded_s"] <= d[k]["serial_s"] + 1e-9 for k in ("small", "big"))
    assert driver["episode_frames"] is None                  # the scales' own episodes unless asked
    assert d["projection"]["frames"] == 10_000_000 and d["projection"]["wall_hours"] > 0
    assert [(d["item"], d["maps_from"], d["workers_hi"]) for d in r["loader"]["dataloader"]] == [
        ("full", "best", cores), ("full", "stored", cores), ("tactile", "best", cores)]
    full, tactile = r["loader"]["dataloader"][0], r["loader"]["dataloader"][2]
    assert tactile["ipc_bytes_per_item"] < full["ipc_bytes_per_item"] / 2   # no RGB, no float coverage, no regions
    assert [row["frames"] for row in r["rss"]] == list(BenchConfig.quick_config(out).rss_lengths)
    assert all(row["peak_rss_mb"] > 10 for row in r["rss"])
    assert {row["mode"] for row in r["raster"]["rows"]} == {"nearest", "bilinear"}
    assert all(row["max_roundtrip_error"] == 0 for row in r["raster"]["rows"] if row["mode"] == "nearest")
    assert [row["workers"] for row in r["validate"]] == [1, 2] and all(row["ok"] for row in r["validate"])
    assert r["loader"]["bound"]["samples_per_s"] > 0 and len(r["loader"]["rows"]) == 7
    assert r["machine"]["cpu_count"] >= 1 and r["machine"]["cpu_model"]
    small, large = r["append"]["rows"]
    assert (small["episodes_before"], large["episodes_before"]) == BenchConfig.quick_config(out).append_sizes
    for row in (small, large):   # the append ran only the new episode and kept every other one as committed
        assert row["units_run"] == 1 and row["episodes_unchanged"] == row["episodes_before"]
        assert 0 < row["bytes_shards"] < row["bytes_written"]
    (size,) = r["size"]["sizes"]                    # the replicated dataset: one unit per recording copy
    assert size["samples"] >= BenchConfig.quick_config(out).size_samples[0] and size["episodes"] == size["units"]
    written = {c["command"].split(" (")[0]: c["bytes_written"] for c in size["commands"]}
    assert written["open"] == written["log"] == written["diff"] == written["gc --dry-run"] == 0   # readers, dry runs
    assert written["rm one episode"] > 0 and written["trim one episode"] > written["rm one episode"]  # + its shard
    stats = r["stats"]
    assert stats["tactile_decode"]["frames"] == stats["runs"]["incremental"]["frames"] > 0
    assert stats["runs"]["warm"]["episodes_computed"] == 0 and stats["runs"]["incremental"]["episodes_computed"] == 1
    # the bench dataset stores raw rows (format 3): stats read them, not the maps
    assert stats["runs"]["cold"]["hand_frames_from_raw"] == stats["runs"]["cold"]["hand_frames"] > 0


def test_defaults_are_computed_from_the_measured_tables(quick_run):
    """Each "Default:" is what its stated criterion picks from the rows beside it, recomputed here."""
    _, out, _ = quick_run
    r = json.loads((out / "results.json").read_text())
    c = r["codecs"]
    # the codec rule on the measured table: smallest EXR codec whose max error keeps every glove's levels
    steps = {m["layout"]: m["step"] for m in c["margins"]}
    keeps = {row["codec"] for row in c["rows"] if row["codec"].startswith("exr_")
             and all(row["max_error"] < step / 2 for step in steps.values())}
    smallest = min((row for row in c["rows"] if row["codec"] in keeps), key=lambda row: row["bytes_per_frame"])
    assert c["default"] == smallest["codec"] == c["code_default"], c["reason"]
    # the stored-map layout: exact for every glove, within the byte budget, fastest (with the tie), smallest
    from htdata.benchmarks.maplayouts import BYTES_BUDGET, TIE
    from htdata.glove.codecrule import ANALYTIC_MAX_ERROR
    exact = [row for row in c["layouts"]
             if all(max(row["max_error"], ANALYTIC_MAX_ERROR[row["pixel"]]) < step / 2 for step in steps.values())]
    cheap = [row for row in exact if row["bytes_per_map"] <= BYTES_BUDGET * min(x["bytes_per_map"] for x in exact)]
    fast = [row for row in cheap if row["encode_ms"] <= (1 + TIE) * min(x["encode_ms"] for x in cheap)]
    assert c["layout_default"] == min(fast, key=lambda row: row["bytes_per_map"])["layout"], c["layout_reason"]
    assert {row["compression"] for row in c["layouts"]} == {"rle", "zips", "zip", "piz"}
    assert {row["writer"] for row in c["layouts"]} == {"htdata (exrzip.py)", "OpenEXR", "OpenImageIO"}
    assert c["per_glove"] == {"opentouch_right_16x16": "exr_float_zip", "touchanything_left_21x21": "exr_half_zip",
                              "touchanything_right_21x21": "exr_half_zip"}
    exact = {row["mode"] for row in r["raster"]["rows"]} - {row["mode"] for row in r["raster"]["rows"]
                                                             if row["max_roundtrip_error"] != 0}
    assert r["raster"]["default"] in exact and r["raster"]["default"] == r["raster"]["code_default"] == "nearest"
    rgb = r["rgb"]
    good = [row["quality"] for row in rgb["jpeg"] if row["psnr_db"] >= 40.0]
    assert rgb["default_quality"] == (min(good) if good else max(rgb["jpeg"], key=lambda x: x["psnr_db"])["quality"])
    from htdata.benchmarks.rgb import PIPELINE_RESIZE
    from htdata.source.rgb import INTERPOLATIONS
    assert set(PIPELINE_RESIZE) == set(INTERPOLATIONS)   # the rule sees every [rgb] interpolation option
    options = [row for row in rgb["resize"] if row["method"] in PIPELINE_RESIZE.values()]
    assert len(options) == len(PIPELINE_RESIZE)
    assert rgb["default_resize"] == min(options, key=lambda row: row["mean_abs_error"])["method"]
    assert not any(v["meets"] for v in rgb["resize_verdicts"] if v["method"] == "cv2_area")
    assert {r["method"] for r in rgb["video_scale"]} >= {"video_rgb24+cv2_area", "swscale_area"}
    assert ("the same" in rgb["reason"]) == ((rgb["default_quality"], rgb["default_resize"])
                                             == (rgb["code_default_quality"], rgb["code_default_resize"]))


def test_report_has_every_table_heading(quick_run):
    _, out, _ = quick_run
    report = (out / "REPORT.md").read_text()
    for heading in HEADINGS.values():
        assert heading in report, heading
    rgb = json.loads((out / "results.json").read_text())["rgb"]
    assert "**Default: exr_float_zip**" in report and "**Default: nearest**" in report
    assert f"**Defaults: JPEG q{rgb['default_quality']}, {rgb['default_resize']}**" in report
    # The probe's markdown verbatim under its name, after the built-in tables; the broken one named.
    assert "## probe" in report and "| ok | " in report
    assert report.index("## probe") > report.index(HEADINGS["validate"])
    assert "## zz_broken" in report and "Not measured: RuntimeError: probe plugin exploded" in report
    assert report.count("Not measured") == 1
    assert report.count("|---|") >= 10


def test_report_names_failed_sections():
    results = {"command": "htdata bench", "quick": True, "seconds": 1.0, "created": "now",
               "errors": {"raster": "RuntimeError: boom", "training": "ImportError: no torch"},
               "plugins": {"training": "handtouch.benchmark:training_section"}}
    text = render_report(results)
    assert "Not measured: RuntimeError: boom" in text
    assert "## training" in text and "Not measured: ImportError: no torch" in text
    assert all(h in text for h in HEADINGS.values())


def test_finite_json_replaces_non_finite():
    import numpy as np

    assert finite_json({"a": float("nan"), "b": [np.float32(1.5), np.int64(3), float("inf")], "c": True}) == \
        {"a": None, "b": [1.5, 3, None], "c": True}


@pytest.mark.parametrize("change, match", [
    ({"rss_lengths": (40, 20)}, "rss_lengths"),
    ({"rgb_frames": 0}, "rgb_frames"),
    ({"sections": ("nope",)}, "unknown section"),
    ({"ingest_workers": ()}, "ingest_workers"),
    ({"ingest_workers": (2, 2)}, "two worker counts"),
    ({"scaling_scale": "huge"}, "scaling_scale"),
    ({"ingest_reps": 0}, "ingest_reps"),
    ({"scale": "huge"}, "scale"),
    ({"driver_scales": ("medium", "tiny")}, "driver_scales"),
    ({"driver_scales": ("tiny", "tiny")}, "driver_scales"),
    ({"driver_sources": ("nope",)}, "driver_sources"),
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


def test_driver_growth_and_projection_arithmetic():
    """Growth = slope between two sizes; 10M frames on 64 cores: wall = fixed + growth x F + max(work, driver run)."""
    from htdata.benchmarks.driver import growth, project

    small = {"frames": 200, "units": 4, "serial_s": 1.02, "serial_cpu_s": 0.51, "run_cpu_s": 0.1}
    big = {"frames": 4200, "units": 84, "serial_s": 1.10, "serial_cpu_s": 0.55, "run_cpu_s": 0.14}
    g = growth(small, big)
    assert g["serial_cpu_growth_s_per_unit"] == pytest.approx(0.04 / 80) and g["frames_per_unit"] == 50
    assert g["frames_per_unit_for_target"] == pytest.approx(0.0005 / 2e-5)      # 25 frames per episode
    assert g["serial_growth_s_per_frame"] == pytest.approx(2e-5) and g["serial_fixed_s"] == pytest.approx(1.016)
    assert g["serial_cpu_growth_s_per_frame"] == pytest.approx(1e-5) and g["run_cpu_s_per_frame"] == pytest.approx(
        0.14 / 4200)
    row = project(g, core_s_per_frame=0.0036)
    serial = 1.016 + 2e-5 * 1e7
    assert row["core_hours"] == pytest.approx(10.0) and row["serial_hours"] == pytest.approx(serial / 3600)
    assert row["wall_hours"] == pytest.approx((serial + 1e7 * 0.0036 / 64) / 3600)
    assert row["speedup"] == pytest.approx((36_000 + serial) / (serial + 562.5))
    slow = project({**g, "run_cpu_s_per_frame": 1e-4}, core_s_per_frame=0.0036)   # the driver caps the run
    assert slow["wall_hours"] == pytest.approx((serial + 1000.0) / 3600)
    with pytest.raises(ValueError, match="two corpus sizes"):
        growth(small, small)


def test_driver_growth_leaves_the_bounded_glove_rest_out_of_the_slope():
    """The pooled glove rest reads at most POOL_MAX recordings a glove: the bigger size's rest seconds are no
    growth; they come back as a fixed term, per pooled recording x POOL_MAX per glove. Without it (older runs,
    no rest keys) the growth is the plain slope."""
    from htdata.benchmarks.driver import growth, size_row
    from htdata.glove.pooledrest import POOL_MAX

    def run(frames, units, plan_cpu, rest_cpu, recordings):
        return {"frames": frames, "units": units, "plan_s": plan_cpu, "commit_s": 0.1, "plan_cpu_s": plan_cpu,
                "commit_cpu_s": 0.1, "run_cpu_s": 0.0, "rest_s": rest_cpu, "rest_cpu_s": rest_cpu,
                "rest_recordings": recordings, "rest_gloves": 1 if recordings else 0, "worker_s": 1.0,
                "worker_cpu_s": 1.0}

    small, big = size_row([run(600, 2, 0.2, 0.0, 0)], "tiny"), size_row([run(6600, 22, 0.6, 0.3, 12)], "small")
    g = growth(small, big)
    assert g["serial_cpu_growth_s_per_frame"] == pytest.approx(0.1 / 6000)          # 0.4 - 0.3 of rest
    assert g["serial_cpu_growth_s_per_unit"] == pytest.approx(0.1 / 20)
    assert g["serial_cpu_rest_fixed_s"] == pytest.approx(0.3 / 12 * POOL_MAX)
    assert g["serial_cpu_fixed_s"] == pytest.approx(0.3 - 0.1 / 6000 * 600 + 0.3 / 12 * POOL_MAX)
    plain = growth({k: v for k, v in small.items() if not k.startswith(("rest", "unbounded"))},
                   {k: v for k, v in big.items() if not k.startswith(("rest", "unbounded"))})
    assert plain["serial_cpu_growth_s_per_frame"] == pytest.approx(0.4 / 6000) and plain["serial_cpu_rest_fixed_s"] == 0


def test_bench_driver_options_are_checked(tmp_path):
    """--driver-episode-frames takes N or LO,HI (htdata sample's rule); --driver-scales two scales, smaller first."""
    with pytest.raises(SystemExit):
        cli_main(["bench", "--quick", "--out", str(tmp_path), "--only", "driver", "--driver-episode-frames", "9,3"])
    assert cli_main(["bench", "--quick", "--out", str(tmp_path), "--only", "driver", "--driver-scales",
                     "small,tiny"]) == 2


def test_gpu_check_results_beside_the_report_get_their_own_section():
    """`make gpu-check` runs elsewhere: its JSON is shown with its machine, the span and the kernel share apart."""
    from htdata.benchmarks.report import render_report

    row = {"batch": 128, "workers": 16, "compile": False, "samples_per_s": 2972.4, "steps_per_s": 23.2,
           "data_wait_share": 0.001, "host_share": 0.99, "gpu_busy_share": 1.0,
           "profile": {"kernel_ms_per_step": 32.3, "kernels_per_step": 1156, "profiled_steps": 20, "top_kernels": []}}
    skipped = {"batch": 128, "workers": 16, "compile": True, "error": "skipped: 330 s spent (--skip-after-s)"}
    results = {"command": "htdata bench", "quick": True, "seconds": 1.0, "created": "today", "plugins": {},
               "errors": {}, "gpu_check": {"file": "gpucheck.json", "device": "NVIDIA H100 80GB HBM3", "cpus": 16,
                                           "torch": "2.11.0+cu130", "rows": [row, skipped]}}
    md = render_report(results)
    section = md.split("## GPU: HandTouch stage 1")[1]
    assert "NVIDIA H100 80GB HBM3 with 16 CPU cores" in section
    assert "| 128 | 16 | no | 2972 | 23.2 | 0% | 99% | 100% | 32.3 | 75% |" in section   # 32.3 of 43.1 ms
    assert "skipped: 330 s spent" in section


def test_a_hard_link_writes_no_bytes_but_a_rewritten_file_does(tmp_path):
    """The HT-Bench-size section's byte count: new names for existing inodes (a copy's shards) write nothing."""
    from htdata.benchmarks.htbenchsize import _files, bytes_written
    (tmp_path / "a").write_bytes(b"x" * 100)
    before = _files(tmp_path)
    os.link(tmp_path / "a", tmp_path / "b")
    (tmp_path / "c").write_bytes(b"y" * 7)
    assert bytes_written(before, _files(tmp_path)) == 7
    (tmp_path / "a").unlink()
    (tmp_path / "a").write_bytes(b"z" * 30)             # a rewrite under an old name
    assert bytes_written(before, _files(tmp_path)) == 37
