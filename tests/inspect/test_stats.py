"""htdata stats: numbers from known taxel series, the content-addressed cache, bad input, CLI, benchmark."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from htdata.cli import main as cli_main
from htdata.glove.layouts import load_layout
from htdata.inspect import stats
from htdata.inspect.episodestats import HIST_BINS, quantile, value_histogram
from htdata.read.reader import DatasetReader
from tests.factories.tactile import LEFT, RIGHT, clean_series, write_taxel_dataset

N = 40


def _one_taxel(value: float, frames: range, cell=(0, 0), n=N) -> np.ndarray:
    g = np.zeros((n, 16, 16), np.float32)
    g[list(frames), cell[0], cell[1]] = value
    return g


@pytest.fixture(scope="module")
def known(tmp_path_factory):
    """ep_a: taxel (0,0) at 0.5 in frames 0..9 of 40, right only; ep_b: smooth contact, both hands."""
    root = tmp_path_factory.mktemp("st") / "ds"
    return write_taxel_dataset(root, [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": {"right": (RIGHT, _one_taxel(0.5, range(10)))}},
        {"episode_id": "ep_b", "task": "wipe", "scene": "kitchen", "fps": 20.0,
         "hands": {"right": (RIGHT, clean_series(RIGHT, 30, seed=1)), "left": (LEFT, clean_series(LEFT, 30, seed=2))}},
    ])


def _glove(summary: dict, **match) -> dict:
    hits = [g for g in summary["gloves"] if all(g.get(k) == v for k, v in match.items())]
    assert len(hits) == 1, (match, [(g.get("layout"), g.get("hand")) for g in summary["gloves"]])
    return hits[0]


def test_histogram_quantiles_are_exact_to_a_bin():
    rng = np.random.default_rng(0)
    values = np.concatenate([np.zeros(5000), rng.beta(0.5, 3.0, 20000), [1.0]])
    zeros, hist = value_histogram(values)
    assert zeros == 5000 and hist.sum() == 20001 and hist[-1] >= 1       # 1.0 lands in the last bin
    for q in (0.01, 0.5, 0.75, 0.99):
        assert abs(quantile(zeros, hist, q) - np.quantile(values, q)) <= 2.0 / HIST_BINS
    assert quantile(0, np.zeros(HIST_BINS, np.int64), 0.5) is None


def test_numbers_of_a_known_episode(known, tmp_path):
    s = stats.dataset_stats(known, cache_dir=tmp_path / "c")
    with DatasetReader(known) as r:
        per_ep, _ = stats.episode_stats(r, [0], cache_dir=tmp_path / "c")
    h = per_ep[0]["hands"]["right"]
    assert h["frames"] == N and h["contact_frames"] == 10
    assert h["max"] == pytest.approx(0.5, abs=1e-3)
    layout = load_layout(RIGHT)
    mean = np.asarray(h["taxel_sum"]) / N
    assert mean[0] == pytest.approx(0.5 * 10 / N, abs=1e-3) and np.all(mean[1:] == 0)
    assert list(np.argwhere(layout.live_mask)[0]) == [0, 0]
    (region,) = [name for name, r in h["regions"].items() if r["contact_frames"]]
    assert h["regions"][region]["contact_frames"] == 10
    assert h["regions"][region]["pressure_sum"] / h["regions"][region]["pressure_count"] == pytest.approx(0.5, abs=1e-3)
    right = _glove(s, layout=RIGHT, hand="right")
    assert right["episodes"] == 2 and right["frames"] == N + 30
    assert right["taxel_mean"][0][0] is not None and right["taxel_mean"][0][2] is None   # (0,2) is not live
    assert s["tasks"]["wipe"] == {"episodes": 1, "frames": 30, "duration_s": 1.5, "hands": {"left": 1, "right": 1}}
    assert s["scenes"]["kitchen"]["episodes"] == 2


def test_merged_sums_equal_one_pass_over_all_frames(known, tmp_path):
    s = stats.dataset_stats(known, cache_dir=tmp_path / "c")
    from htdata.glove.rasterise import Rasteriser
    layout = load_layout(RIGHT)
    r = Rasteriser(layout)
    with DatasetReader(known) as reader:
        maps = np.stack([reader.decoded(i)["tactile"]["right"] for i in range(len(reader))])
    x = r.sample(maps)[:, layout.live_mask]
    right = _glove(s, layout=RIGHT, hand="right")
    got = np.asarray([v for row in right["taxel_mean"] for v in row if v is not None])
    assert np.allclose(got, x.mean(axis=0), atol=1e-6)
    std = np.asarray([v for row in right["taxel_std"] for v in row if v is not None])
    assert np.allclose(std, x.std(axis=0), atol=1e-5)
    assert right["contact_fraction"] == pytest.approx((x > 0.02).any(axis=1).mean(), abs=1e-6)


def test_cache_is_content_addressed_and_incremental(known, tmp_path):
    cache = tmp_path / "c"
    first = stats.dataset_stats(known, cache_dir=cache)
    assert first["cache"]["computed"] == 2 and len(list(cache.glob("*.json"))) == 2
    mtimes = {p.name: p.stat().st_mtime_ns for p in cache.glob("*.json")}
    again = stats.dataset_stats(known, cache_dir=cache)
    assert again["cache"] == {**first["cache"], "computed": 0, "cached": 2, "frames_computed": 0}
    assert {p.name: p.stat().st_mtime_ns for p in cache.glob("*.json")} == mtimes      # never rewritten
    assert {k: v for k, v in again.items() if k != "cache"} == {k: v for k, v in first.items() if k != "cache"}
    # the same two episodes (same shard bytes) plus one more: only the new one is computed
    bigger = write_taxel_dataset(tmp_path / "bigger", [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": {"right": (RIGHT, _one_taxel(0.5, range(10)))}},
        {"episode_id": "ep_b", "task": "wipe", "scene": "kitchen", "fps": 20.0,
         "hands": {"right": (RIGHT, clean_series(RIGHT, 30, seed=1)), "left": (LEFT, clean_series(LEFT, 30, seed=2))}},
        {"episode_id": "ep_c", "hands": {"right": (RIGHT, clean_series(RIGHT, 12, seed=5))}}])
    third = stats.dataset_stats(bigger, cache_dir=cache)
    assert third["cache"]["computed"] == 1 and third["cache"]["frames_computed"] == 12


def test_default_cache_lives_in_the_dataset(known):
    stats.dataset_stats(known)
    assert len(list((known / stats.STATS_DIR).glob("*.json"))) == 2


def test_by_groupings(known, tmp_path):
    cache = tmp_path / "c"
    by_task = stats.dataset_stats(known, by="task", cache_dir=cache)
    assert _glove(by_task, task="pour", layout=RIGHT, hand="right")["frames"] == N
    assert _glove(by_task, task="wipe", layout=LEFT, hand="left")["frames"] == 30
    by_hand = stats.dataset_stats(known, by="hand", cache_dir=cache)
    assert _glove(by_hand, hand="right")["frames"] == N + 30
    by_layout = stats.dataset_stats(known, by="layout", cache_dir=cache)
    assert _glove(by_layout, layout=LEFT)["frames"] == 30
    with pytest.raises(ValueError, match="--by"):
        stats.dataset_stats(known, by="colour", cache_dir=cache)


def test_bad_input_empty_one_frame_all_zero_absent_hand_nan(tmp_path, capsys):
    empty = write_taxel_dataset(tmp_path / "empty", [])
    s = stats.dataset_stats(empty)
    assert s["episodes"] == 0 and s["gloves"] == [] and s["tasks"] == {}
    assert cli_main(["stats", str(empty)]) == 0 and "no tactile frames" in capsys.readouterr().out

    one = write_taxel_dataset(tmp_path / "one", [{"episode_id": "ep1", "hands": {"right": (RIGHT, _one_taxel(0.3, [0], n=1))}}])
    g = _glove(stats.dataset_stats(one), layout=RIGHT, hand="right")
    assert g["frames"] == 1 and g["contact_fraction"] == 1.0
    assert g["health"]["episodes_not_assessed"] == 1 and g["health"]["taxels_assessed"] == 0

    zero = write_taxel_dataset(tmp_path / "zero", [{"episode_id": "z", "hands": {"right": (RIGHT, np.zeros((35, 16, 16)))}}])
    s = stats.dataset_stats(zero)
    g = _glove(s, layout=RIGHT, hand="right")
    assert g["contact_fraction"] == 0.0 and g["quantiles"] == {"p1": 0.0, "p50": 0.0, "p99": 0.0, "max": 0.0}
    assert all(r["mean_pressure"] is None for r in g["regions"].values())
    assert sum(g["health"]["counts"].values()) == 0
    assert s["tasks"]["pour"]["hands"] == {"left": 0, "right": 1}        # the left hand is absent everywhere
    assert [x["hand"] for x in s["gloves"]] == ["right"]

    nan = write_taxel_dataset(tmp_path / "nan", [{"episode_id": "n", "nan_frames": {"right": [3]},
                                                  "hands": {"right": (RIGHT, _one_taxel(0.5, range(5), n=8))}}])
    s = stats.dataset_stats(nan)
    assert [(b["episode"], b["frame"], b["hand"], b["key"]) for b in s["nan_samples"]] == [("n", 3, "right", "n__000003")]
    assert _glove(s, layout=RIGHT, hand="right")["frames"] == 7
    assert cli_main(["stats", str(nan)]) == 0
    assert "n__000003 (right hand, episode n frame 3)" in capsys.readouterr().err


def test_cli_text_json_and_health_png(known, tmp_path, capsys):
    assert cli_main(["stats", str(known)]) == 0
    out = capsys.readouterr().out
    assert f"{RIGHT} / right: 2 episodes, {N + 30} frames" in out and "wipe" in out
    assert cli_main(["stats", str(known), "--json", "--by", "scene", "--no-cache"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["by"] == "scene" and doc["cache"]["dir"] is None
    png = tmp_path / "health.png"
    assert cli_main(["stats", str(known), "--health", str(png)]) == 0
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 224 and img.shape[1] >= 2 * 224   # one panel per glove
    assert cli_main(["stats", str(tmp_path / "missing")]) == 2


def test_stats_benchmark_reports_cold_warm_incremental(known):
    runs = stats.stats_benchmark(known)
    assert set(runs) == {"cold", "warm", "incremental"}
    assert runs["cold"]["episodes_computed"] == 1 and runs["warm"]["episodes_computed"] == 0
    assert runs["incremental"]["episodes_computed"] == 1 and runs["incremental"]["frames_computed"] == 30
    assert all(r["frames_per_s"] > 0 for r in runs.values())
    assert not (known / stats.STATS_DIR).exists() or all(
        p.stat().st_size for p in (known / stats.STATS_DIR).glob("*.json"))


def test_unwritable_cache_still_gives_stats(known, tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")                     # the cache dir cannot be created under it
    s = stats.dataset_stats(known, cache_dir=blocker / "stats")
    assert s["cache"]["computed"] == 2 and "a_file" in s["cache"]["cache_error"]
    assert _glove(s, layout=RIGHT, hand="right")["frames"] == N + 30


# -- values from the stored raw rows (format 3) --------------------------------------------------------

RAW_FRAMES = 45


@pytest.fixture(scope="module")
def raw_ds(tmp_path_factory):
    """A native recording (100 Hz OpenTouch-layout glove, 30 Hz video: several raw rows per sample) ingested
    with raw rows; values are integer firmware counts with a moving press, so every level is known."""
    from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
    from tests.factories import PERIOD, ingest_cli

    root = tmp_path_factory.mktemp("rawstats")
    t_video = np.arange(RAW_FRAMES, dtype=np.int64) * PERIOD
    t_glove = np.arange(0, RAW_FRAMES * PERIOD, 10_000_000, dtype=np.int64)
    rng = np.random.default_rng(3)
    values = np.full((t_glove.size, 16, 16), 3072.0, np.float32)           # no load
    for k in range(t_glove.size):
        r = (k // 6) % 12
        values[k, r:r + 3, 4:9] = rng.integers(0, 2900, (3, 5))                # a press moving down the grid
    rec = NativeRecording(task="grasp", scene="lab", video_storage="jpeg",
                          video_frames=[np.full((40, 40, 3), (30, 160, 220), np.uint8)] * RAW_FRAMES,
                          video_timestamps_ns=t_video,
                          hands={"right": NativeHand("opentouch_right_16x16", values, t_glove)})
    write_native_recording(root / "src" / "rec_a", rec)
    # baseline "none": the exact values below (an inverted raw-count glove otherwise gets the raw-count default)
    assert ingest_cli("--pipeline", "native", "--set", "tactile.maps=stored", "--set",
                      "normalise.opentouch_right_16x16.baseline=none", root / "src", root / "ds") == 0
    return root / "ds"


def _paired_raw_rows(root) -> np.ndarray:
    """The raw row paired with every sample, read back independently of htdata.inspect.episodestats."""
    from htdata.format.codec import decode_json, decode_npy

    out = []
    with DatasetReader(root) as r:
        for i in range(len(r)):
            m = r.sample(i, ("json", "raw_right.npy"))
            out.append(decode_npy(m["raw_right.npy"])[decode_json(m["json"])["raw_paired"]["right"]])
    return np.stack(out)


def test_values_come_from_the_raw_rows_with_raw_quantiles(raw_ds, tmp_path):
    s = stats.dataset_stats(raw_ds, cache_dir=tmp_path / "c")
    g = _glove(s, layout="opentouch_right_16x16", hand="right")
    assert g["frames"] == g["frames_from_raw"] > 0
    live = load_layout("opentouch_right_16x16").live_mask
    raw = _paired_raw_rows(raw_ds)[:, live].astype(np.float64)
    q = g["raw_quantiles"]
    assert q["min"] == raw.min() and q["max"] == raw.max() and q["range"] == [0.0, 3072.0]
    bin_width = 3072.0 / HIST_BINS
    ordered = np.sort(raw.ravel())
    for name, level in (("p1", 0.01), ("p50", 0.5), ("p99", 0.99)):
        rank = level * (ordered.size - 1)     # between the two order statistics around the rank, to a bin
        lo, hi = ordered[int(np.floor(rank))], ordered[int(np.ceil(rank))]
        assert lo - bin_width <= q[name] <= hi + bin_width, (name, q[name], lo, hi)
    # normalised values are exact: (3072 - raw) / 3072 for this inverted glove, no baseline
    assert g["quantiles"]["max"] == pytest.approx(float(((3072.0 - raw) / 3072.0).max()), abs=1e-7)
    assert "raw rows" in s["values"]


def test_cli_prints_raw_quantiles_only_where_raw_rows_exist(raw_ds, known, capsys):
    assert cli_main(["stats", str(raw_ds)]) == 0
    assert "raw (glove units" in capsys.readouterr().out
    assert cli_main(["stats", str(known)]) == 0
    assert "raw (glove units" not in capsys.readouterr().out


def test_raw_path_and_map_path_agree_to_the_map_codec_error(raw_ds, tmp_path, monkeypatch):
    from htdata.inspect import episodestats

    with DatasetReader(raw_ds) as r:
        gloves = episodestats.dataset_gloves(r)
        from_raw = episodestats.compute_episode(r, 0, gloves)["hands"]["right"]
        monkeypatch.setattr(episodestats, "raw_hands", lambda reader, pos: [])      # what a format 2 dataset gets
        from_maps = episodestats.compute_episode(r, 0, gloves)["hands"]["right"]
    assert (from_raw["values_from"], from_maps["values_from"]) == ("raw", "maps") and "raw_hist" not in from_maps
    assert from_raw["frames"] == from_maps["frames"] and from_raw["contact_frames"] == from_maps["contact_frames"]
    codec_error = 2.0 ** -12 if r.manifest["codec"]["tactile"].get("pixel_type", "half") == "half" else 0.0
    n = from_raw["frames"]
    assert np.allclose(from_raw["taxel_sum"], from_maps["taxel_sum"], atol=n * codec_error + 1e-9)
    # health: from the raw counts where stored (htdata/glove/rawhealth.py), from the maps otherwise
    assert (from_raw["health"]["basis"], from_maps["health"]["basis"]) == ("raw", "maps")
    assert from_raw["health"]["live"] == from_maps["health"]["live"]


def test_datasets_without_raw_rows_fall_back_to_maps(known, tmp_path):
    s = stats.dataset_stats(known, cache_dir=tmp_path / "c")
    for g in s["gloves"]:
        assert g["frames_from_raw"] == 0 and "raw_quantiles" not in g



def test_episode_stats_keep_the_callers_order_and_count_cached_entries(known, tmp_path):
    with DatasetReader(known) as r:
        per_ep, info = stats.episode_stats(r, [1, 0], cache_dir=tmp_path / "c")
        assert [e["episode_id"] for e in per_ep] == ["ep_b", "ep_a"] and info["computed"] == 2
        seen = []
        again, info = stats.episode_stats(r, [0, 1, 0], cache_dir=tmp_path / "c", progress=lambda d, n: seen.append((d, n)))
    assert [e["episode_id"] for e in again] == ["ep_a", "ep_b", "ep_a"] and info["cached"] == 2
    assert info["computed"] == 0 and seen == [(2, 2)] and again[1] == per_ep[0]


def test_map_finiteness_by_bits_matches_numpy_on_every_half_pattern():
    from htdata.inspect.episodestats import all_finite

    halves = np.arange(65536, dtype=np.uint32).astype(np.uint16).view(np.float16)
    assert [all_finite(halves[i:i + 1]) for i in range(0, 65536, 1)] == np.isfinite(halves).tolist()
    assert all_finite(np.zeros((224, 224), np.float32)) and not all_finite(np.array([np.inf], np.float32))


# --------------------------------------------------------------------------- words that match; a scale from the data


@pytest.fixture(scope="module")
def rawknit(tmp_path_factory):
    from tests.factories import ingest_rawglove
    return ingest_rawglove(tmp_path_factory.mktemp("rawknit"), clips=2)


def test_brief_names_the_contact_rule_actually_used(rawknit, known, capsys):
    assert cli_main(["stats", str(rawknit), "--brief", "--no-cache"]) == 0
    out = capsys.readouterr().out
    assert "above 0.02" not in out          # the calibrated gloves do not use the old threshold
    assert "contact = a frame with at least" in out and "quantisation steps above their noise floor" in out
    assert cli_main(["stats", str(known), "--brief", "--no-cache"]) == 0     # no noise floor: the old rule, said so
    assert "contact = a frame with any taxel > 0.02" in capsys.readouterr().out


def test_scale_is_suggested_for_faint_gloves_only(tmp_path):
    from htdata.inspect.scalehint import SUGGEST_BELOW, scale_suggestions

    faint = write_taxel_dataset(tmp_path / "faint", [{"episode_id": f"f{k}", "hands": {
        "right": (RIGHT, clean_series(RIGHT, 40, seed=k, blobs=4) * 0.15)}} for k in range(2)])
    strong = write_taxel_dataset(tmp_path / "strong", [{"episode_id": "s", "hands": {
        "right": (RIGHT, np.clip(clean_series(RIGHT, 40, seed=4, blobs=4) * 3.0, 0, 1))}}])
    hint = stats.dataset_stats(faint, cache_dir=None)["scale"][RIGHT]
    # the p99.9 of the values above the contact level (0.02), from the raw values the factory wrote
    values = np.concatenate([clean_series(RIGHT, 40, seed=k, blobs=4) * 0.15 for k in range(2)])
    values = values[:, load_layout(RIGHT).live_mask].ravel()
    p999 = float(np.quantile(values[values > 0.02], 0.999))
    assert hint["p99_9"] == pytest.approx(p999, abs=0.002) and hint["p99_9"] < SUGGEST_BELOW
    assert hint["suggested_scale"] <= 1.0 / hint["p99_9"] < hint["suggested_scale"] * 1.1     # rounded down
    assert hint["toml"] == f"[normalise.{RIGHT}]\nscale = {hint['suggested_scale']:g}"
    assert stats.dataset_stats(strong, cache_dir=None)["scale"][RIGHT]["suggested_scale"] is None
    # firm presses at ~0.4 (the sample world's left glove) are not faint: no hint on the project's own data
    firm = write_taxel_dataset(tmp_path / "firm", [{"episode_id": "m", "hands": {
        "right": (RIGHT, clean_series(RIGHT, 40, seed=5, blobs=4) * 0.75)}}])
    firm_hint = stats.dataset_stats(firm, cache_dir=None)["scale"][RIGHT]
    assert 0.3 < firm_hint["p99_9"] < 0.5 and firm_hint["suggested_scale"] is None, firm_hint
    with DatasetReader(faint) as r:        # too few pressed values: nothing suggested, and why
        few = scale_suggestions(r, [{"hands": {"right": {"layout": RIGHT, "contact_rule": {"level": 0.02},
                                                         "hist": [0] * 100 + [5] + [0] * (HIST_BINS - 101)}}}])
    assert few[RIGHT]["suggested_scale"] is None and "need" in few[RIGHT]["reason"]


def test_the_suggested_scale_pasted_into_the_pipeline_fills_the_colour_scale(rawknit, capsys):
    assert cli_main(["stats", str(rawknit), "--brief", "--no-cache"]) == 0
    out = capsys.readouterr().out
    hints = stats.dataset_stats(rawknit, cache_dir=None)["scale"]
    faint = [lid for lid, h in hints.items() if h["suggested_scale"]]
    assert faint, hints
    lid = faint[0]
    scale = hints[lid]["suggested_scale"]
    assert f"    [normalise.{lid}]\n    scale = {scale:g}\n" in out          # the lines to paste, as printed
    assert hints[lid]["pipelines"] == ["native"]    # ingested with the shipped pipeline: copy it first, then use it
    assert "  first: htdata pipelines show native > my_native.toml" in out, out
    assert f"  then: htdata renormalise {rawknit} --pipeline my_native.toml" in out, out
    pipe = rawknit.parent / "rawknit.toml"
    pipe.write_text(pipe.read_text().replace(f"[normalise.{lid}]\n", f"[normalise.{lid}]\nscale = {scale:g}\n"))
    assert cli_main(["renormalise", str(rawknit), "--pipeline", str(pipe)]) == 0
    after = stats.dataset_stats(rawknit, cache_dir=None)["scale"][lid]
    assert after["scale"] == scale and after["suggested_scale"] is None
    assert 0.85 <= after["p99_9"] <= 1.0                  # the strongest presses now reach the top of 0..1
