"""Tactile-video lag from the content (htdata/source/lag.py, pipeline `[sync] lag`).

Recordings are sample-world episodes written as native recordings whose
glove clock runs a known lag off the video while recording.json claims the
clocks agree (htdata.benchmarks.lag.write_shifted_native).
"""

import json

import numpy as np
import pytest

from htdata.benchmarks.lag import planned_episode, write_shifted_native
from htdata.glove.normalisesettings import NormaliseSettings
from htdata.source.lag import THUMB, LagDecision, episode_lag, estimate_episode_lag, estimate_lag
from htdata.source.syncsettings import SyncConfig
from htdata.store.manifest import load_episodes
from tests.factories import ingest_cli

FRAME_MS = 1000 / 30
IMAGE = (160, 160)


def _decide(ref, cfg, adapter, hands):
    """episode_lag as the ingest calls it: the pipeline's sections, never the pipeline (htdata/ingest/episode.py)."""
    return episode_lag(ref, adapter, cfg.adapter.params, cfg.normalise_settings(), cfg.sync, hands)


def _estimate_with(ref, cfg, adapter, hands):
    return estimate_episode_lag(ref, adapter, cfg.adapter.params, cfg.normalise_settings(), cfg.sync, hands)


def _estimate(folder, **overrides):
    cfg, adapter, ref = planned_episode(folder)
    settings = ['sync.lag="estimate"'] + [f"sync.{k}={v}" for k, v in overrides.items()]
    cfg = cfg.with_overrides(settings)
    return cfg, adapter, ref, _estimate_with(ref, cfg, adapter, list(ref.hands))


@pytest.mark.parametrize("lag_ms", [-200.0, -50.0, 100.0])
def test_known_lag_recovered_within_one_frame(tmp_path, lag_ms):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 90, lag_ms, image=IMAGE)
    cfg, adapter, ref, est = _estimate(folder)
    assert est.why == "" and est.confidence >= cfg.sync.min_confidence
    assert abs(est.lag_ns / 1e6 - lag_ms) <= FRAME_MS
    decision = _decide(ref, cfg, adapter, list(ref.hands))
    assert decision.applied and decision.shift_ns == est.lag_ns
    assert decision.to_dict()["applied"] is True and decision.to_dict()["lag_ms"] == pytest.approx(est.lag_ns / 1e6)


def test_two_hands_other_task(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "power_grasp", 5, 90, -50.0, hands=("left", "right"),
                                  image=IMAGE)
    _, _, _, est = _estimate(folder)
    assert est.why == "" and abs(est.lag_ns / 1e6 + 50.0) <= FRAME_MS


def test_glove_without_contact_changes_declines(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 90, 100.0, touching=False, image=IMAGE)
    cfg, adapter, ref, est = _estimate(folder)
    assert est.lag_ns is None and est.confidence == 0.0 and est.why.startswith("no contact changes")
    decision = _decide(ref, cfg, adapter, list(ref.hands))
    assert not decision.applied and decision.shift_ns == 0 and "no contact changes" in decision.reason


def test_random_contact_is_not_confident():
    # Contact that the picture cannot predict at any lag: a low confidence, not an invented lag.
    rng = np.random.default_rng(0)
    n = 120
    t_rgb = np.arange(n, dtype=np.int64) * 33_333_333
    x = np.linspace(0, 1, n)
    thumbs = (np.outer(np.sin(6 * x), np.ones(THUMB * THUMB)) * 40 + rng.normal(0, 1, (n, THUMB * THUMB)))
    t_tac = np.arange(400, dtype=np.int64) * 10_000_000
    est = estimate_lag(t_rgb, thumbs.astype(np.float32), {"right": (t_tac, rng.uniform(0, 1, 400))}, 300_000_000)
    assert est.confidence < 0.5


def test_very_short_episode_declines(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 12, -50.0, image=IMAGE)
    _, _, _, est = _estimate(folder)
    assert est.lag_ns is None and est.confidence == 0.0 and est.why.startswith("too short")


def test_flat_video_declines():
    t_rgb = np.arange(60, dtype=np.int64) * 33_333_333
    t_tac = np.arange(200, dtype=np.int64) * 10_000_000
    contact = np.clip(np.sin(np.linspace(0, 3, 200)), 0, 1)
    est = estimate_lag(t_rgb, np.full((60, THUMB * THUMB), 90, np.float32), {"right": (t_tac, contact)},
                       200_000_000)
    assert est.lag_ns is None and est.why.startswith("flat video")


def test_best_lag_beyond_the_searched_range_is_not_applied(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 90, -200.0, image=IMAGE)
    cfg, adapter, ref, est = _estimate(folder, max_lag_ms=100)
    assert est.confidence == 0.0 and "edge of the searched range" in est.why
    assert not _decide(ref, cfg, adapter, list(ref.hands)).applied


def test_duplicated_and_unordered_timestamps(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 90, 100.0, image=IMAGE)
    npz = folder / "tactile_right.npz"
    with np.load(npz) as f:
        values, ts = f["values"].copy(), f["timestamps_ns"].copy()
    ts[41] = ts[40]                                    # an exact duplicate (the second is dropped)
    perm = np.arange(ts.size)
    perm[100:110] = perm[100:110][::-1]                # rows stored out of time order
    np.savez(npz, values=values[perm], timestamps_ns=ts[perm])
    rgb_ts = np.load(folder / "ego_timestamps.npy")
    rgb_ts[30] = rgb_ts[29]                            # a duplicated video timestamp
    np.save(folder / "ego_timestamps.npy", rgb_ts)
    _, _, _, est = _estimate(folder)
    assert est.why == "" and abs(est.lag_ns / 1e6 - 100.0) <= FRAME_MS


def test_unreadable_episode_declines_naming_why(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 40, 0.0, image=IMAGE)
    cfg, adapter, ref = planned_episode(folder)
    (folder / "tactile_right.npz").write_bytes(b"not an npz")
    est = _estimate_with(ref, cfg.with_overrides(['sync.lag="estimate"']), adapter, ["right"])
    assert est.lag_ns is None and est.why.startswith("could not read the episode")


def test_fixed_lag_and_none(tmp_path):
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 40, 0.0, image=IMAGE)
    cfg, adapter, ref = planned_episode(folder)
    assert _decide(ref, cfg, adapter, ["right"]) is None          # default "none": nothing at all
    fixed = _decide(ref, cfg.with_overrides(["sync.lag=-12.5"]), adapter, ["right"])
    assert fixed == LagDecision("fixed", -12_500_000, True, fixed.reason) and "fixed" in fixed.reason


def _ingest(tmp_path, raw, *settings):
    out = tmp_path / "ds"
    args = [a for s in settings for a in ("--set", s)]
    assert ingest_cli("--pipeline", "native", *args, raw, out) == 0
    (record,) = load_episodes(out)
    report = json.loads((out / "reports" / "ingest.json").read_text())
    return out, record, report


def test_ingest_with_estimate_records_and_applies_it(tmp_path):
    from htdata.read.reader import DatasetReader

    write_shifted_native(tmp_path / "raw" / "rec", "pinch_pick", 3, 90, -200.0, image=IMAGE)
    out, record, report = _ingest(tmp_path, tmp_path / "raw", 'sync.lag="estimate"')
    lag = record["sync"]["lag"]
    assert lag["mode"] == "estimate" and lag["applied"] is True
    assert abs(lag["lag_ms"] + 200.0) <= FRAME_MS and lag["confidence"] >= 0.5
    assert report["sync"][record["episode_id"]]["lag"] == lag
    # The glove's rows now pair on the video clock: every frame pairs within the 20 ms tolerance
    # (as recorded, -200 ms would have lost the first 200 ms of video to "tactile_out_of_range").
    assert record["sync"]["kept"] == 90
    reader = DatasetReader(out)
    meta = json.loads(reader.sample(0)["json"])
    assert abs(meta["sync_offset_ns"]["right"]) <= 20_000_000
    # Stored tactile times are on the RGB clock, so the dataset validates (sync skew, monotonic times).
    from htdata.validate import validate_dataset

    checks = validate_dataset(out)["checks"]
    assert checks["time"]["status"] == "pass" and checks["time"]["checked"]["skews"] == 90, checks["time"]
    # the dataset card draws the applied lags
    from htdata.cli import main as cli_main

    assert cli_main(["card", str(out), str(tmp_path / "card.html")]) == 0
    html = (tmp_path / "card.html").read_text()
    assert "1 episodes asked, 1 applied" in html and "applied lag (ms)" in html


def test_ingest_default_records_no_lag(tmp_path):
    write_shifted_native(tmp_path / "raw" / "rec", "pinch_pick", 3, 40, 0.0, image=IMAGE)
    _, record, _ = _ingest(tmp_path, tmp_path / "raw")
    assert "lag" not in record["sync"]


def test_ingest_estimate_declined_keeps_clocks(tmp_path):
    write_shifted_native(tmp_path / "raw" / "rec", "pinch_pick", 3, 60, 0.0, touching=False, image=IMAGE)
    _, record, _ = _ingest(tmp_path, tmp_path / "raw", 'sync.lag="estimate"')
    lag = record["sync"]["lag"]
    assert lag["applied"] is False and lag["lag_ms"] is None and "no contact changes" in lag["reason"]
    assert lag["estimate"]["why"].startswith("no contact changes")
    assert any(n.startswith("tactile-video lag not applied: no contact changes") for n in record["notes"])


@pytest.mark.parametrize("setting, message", [('sync.lag="guess"', "lag"), ("sync.lag=nan", "finite"),
                                              ("sync.max_lag_ms=0", "max_lag_ms"),
                                              ("sync.min_confidence=1.5", "min_confidence"),
                                              ("sync.lag=true", "lag"), ("sync.lag_ms=3", "lag_ms")])
def test_pipeline_refuses_bad_lag_settings(setting, message):
    from htdata.ingest.pipeline import load_pipeline

    with pytest.raises(ValueError, match=message):
        load_pipeline("native").with_overrides([setting])


def test_pipeline_lag_defaults_keep_the_settings_document():
    from htdata.ingest.pipeline import load_pipeline

    cfg = load_pipeline("native")
    assert cfg.to_dict()["sync"] == {"max_skew_ms": 20.0, "policy": "nearest"}
    est = cfg.with_overrides(['sync.lag="estimate"', "sync.max_lag_ms=300"])
    assert est.to_dict()["sync"] == {"max_skew_ms": 20.0, "policy": "nearest", "lag": "estimate", "max_lag_ms": 300.0}
    assert est.with_overrides([]).to_dict() == est.to_dict()      # round trip through the settings document


def test_look_alikes_match_brute_force_within_the_time_window():
    from htdata.source.lag import NEIGHBOURS, SEARCH_S, look_alikes

    rng = np.random.default_rng(1)
    t = np.arange(500) * 0.5                                   # 250 s, longer than the search window
    feats = np.stack([np.sin(2 * np.pi * t / 7.3), np.cos(2 * np.pi * t / 11.0)], axis=1) + rng.normal(0, .01, (500, 2))
    nb, ok = look_alikes(feats, t, exclude_s=1.0)
    assert ok.all()
    for i in range(0, 500, 37):
        gap = np.abs(t - t[i])
        allowed = np.flatnonzero((gap >= 1.0) & (gap <= SEARCH_S))
        d = ((feats[allowed] - feats[i]) ** 2).sum(axis=1)
        assert set(nb[i]) == set(allowed[np.argsort(d)[:NEIGHBOURS]])


def test_the_lag_needs_only_the_sync_section_and_the_normalisation(tmp_path):
    # No pipeline at all: what the source layer reads is its own sections (a fixed lag opens nothing).
    folder = write_shifted_native(tmp_path / "rec", "pinch_pick", 3, 40, 0.0, image=IMAGE)
    _, adapter, ref = planned_episode(folder)
    plain = NormaliseSettings(name="plain")
    assert episode_lag(ref, adapter, {}, plain, SyncConfig(), ["right"]) is None
    fixed = episode_lag(ref, adapter, {}, plain, SyncConfig(lag=7.5), ["right"])
    assert (fixed.mode, fixed.shift_ns, fixed.applied) == ("fixed", 7_500_000, True)
    assert SyncConfig(max_lag_ms=100.0).max_lag_ns == 100_000_000 and SyncConfig(max_skew_ms=0.5).max_skew_ns == 500_000
