import numpy as np
import pytest

from htdata.source.sync import clean_timestamps, nearest, pair

MS = 1_000_000


def brute_nearest(sorted_ts, q):
    return np.array([int(np.argmin(np.abs(sorted_ts - x))) for x in q])


def test_equal_rates_zero_offset():
    ts = np.arange(50, dtype=np.int64) * 33 * MS
    r = pair(ts, {"right": ts.copy()}, max_skew_ns=5 * MS)
    np.testing.assert_array_equal(r.rgb_index, np.arange(50))
    np.testing.assert_array_equal(r.tactile_index["right"], np.arange(50))
    assert not r.dropped
    h = r.report["hands"]["right"]
    assert h["offset_ns"] == 0 and h["max_abs_skew_ns"] == 0 and h["drift_ns_per_s"] == 0.0


def test_100hz_tactile_30hz_video_with_offset_matches_brute_force():
    t_tac = np.arange(0, 2_000 * MS, 10 * MS, dtype=np.int64)          # 100 Hz, 2 s
    t_rgb = np.arange(0, 1_900 * MS, 33_333_333, dtype=np.int64) + 3 * MS  # 30 Hz, +3 ms
    r = pair(t_rgb, {"left": t_tac}, max_skew_ns=6 * MS)
    assert not r.dropped
    np.testing.assert_array_equal(r.tactile_index["left"], brute_nearest(t_tac, t_rgb))
    assert np.all(np.abs(r.skew_ns["left"]) <= 5 * MS)
    np.testing.assert_array_equal(r.skew_ns["left"], t_rgb - t_tac[r.tactile_index["left"]])


def test_constant_offset_and_drift_are_reported():
    t_rgb = np.arange(100, dtype=np.int64) * 33 * MS
    # tactile clock runs 1 ms/s slow and 2 ms behind -> skew = 2ms + 1ms/s * t
    t_tac = t_rgb - 2 * MS - (t_rgb // 1000)
    r = pair(t_rgb, {"right": t_tac}, max_skew_ns=10 * MS)
    h = r.report["hands"]["right"]
    assert abs(h["drift_ns_per_s"] - 1e6) < 1e3
    assert abs(h["offset_ns"] - (2 * MS + 1.6 * MS)) < 0.1 * MS  # median at t~1.6 s


def test_jitter_keeps_nearest_pairs():
    rng = np.random.default_rng(0)
    base = np.arange(200, dtype=np.int64) * 33 * MS
    t_tac = base + rng.integers(-3 * MS, 3 * MS, size=200)
    t_rgb = base + rng.integers(-3 * MS, 3 * MS, size=200)
    r = pair(t_rgb, {"right": np.sort(t_tac)}, max_skew_ns=8 * MS)
    assert not r.dropped
    np.testing.assert_array_equal(r.tactile_index["right"], brute_nearest(np.sort(t_tac), t_rgb))


def test_tactile_starting_later_drops_early_frames_with_reason():
    t_rgb = np.arange(30, dtype=np.int64) * 33 * MS
    t_left = t_rgb.copy()
    t_right = t_rgb[10:].copy()              # right glove starts 10 frames late
    r = pair(t_rgb, {"left": t_left, "right": t_right}, max_skew_ns=5 * MS)
    np.testing.assert_array_equal(r.rgb_index, np.arange(10, 30))
    assert r.dropped == [(i, "tactile_out_of_range:right") for i in range(10)]
    assert r.report["drops"] == 10 and r.report["kept"] == 20
    assert r.report["drop_reasons"] == {"tactile_out_of_range:right": 10}


def test_gap_inside_stream_is_a_sync_skew_drop():
    t_rgb = np.arange(10, dtype=np.int64) * 33 * MS
    t_tac = np.delete(t_rgb, [5])
    r = pair(t_rgb, {"right": t_tac}, max_skew_ns=10 * MS)
    assert r.dropped == [(5, "sync_skew:right")]


def test_duplicates_keep_first_and_are_counted():
    t = np.array([0, 10, 10, 20, 30, 30, 30], dtype=np.int64) * MS
    order, rep = clean_timestamps(t, "rgb")
    np.testing.assert_array_equal(order, [0, 1, 3, 4])
    assert rep.duplicates == 3 and rep.reordered == 0 and rep.warnings
    r = pair(t, {"right": np.array([0, 10, 20, 30], dtype=np.int64) * MS}, max_skew_ns=MS)
    np.testing.assert_array_equal(r.rgb_index, [0, 1, 3, 4])
    assert sorted(i for i, why in r.dropped if why == "duplicate_timestamp") == [2, 5, 6]
    assert r.report["rgb_duplicates"] == 3


def test_non_monotonic_is_stable_sorted_with_warning():
    t = np.array([0, 20, 10, 30, 10], dtype=np.int64)
    order, rep = clean_timestamps(t, "tactile_left")
    np.testing.assert_array_equal(order, [0, 2, 1, 3])  # first 10 (index 2) kept, index 4 dup
    assert rep.reordered > 0 and rep.duplicates == 1
    assert any("not monotonic" in w for w in rep.warnings)
    assert np.all(np.diff(t[order]) > 0)


def test_non_monotonic_tactile_maps_back_to_original_indices():
    t_rgb = np.array([0, 10, 20, 30], dtype=np.int64) * MS
    t_tac = np.array([30, 0, 20, 10], dtype=np.int64) * MS
    r = pair(t_rgb, {"right": t_tac}, max_skew_ns=0)
    np.testing.assert_array_equal(r.tactile_index["right"], [1, 3, 2, 0])
    assert r.report["hands"]["right"]["reordered"] > 0


def test_single_frame():
    r = pair(np.array([5 * MS]), {"right": np.array([4 * MS])}, max_skew_ns=2 * MS)
    np.testing.assert_array_equal(r.rgb_index, [0])
    h = r.report["hands"]["right"]
    assert h["offset_ns"] == MS and h["drift_ns_per_s"] == 0.0


def test_all_dropped_gives_empty_result_not_nan():
    r = pair(np.array([0, 1000 * MS]), {"right": np.array([500 * MS])}, max_skew_ns=MS)
    assert r.rgb_index.size == 0 and r.report["kept"] == 0
    assert r.report["hands"]["right"]["offset_ns"] is None


@pytest.mark.parametrize("rgb,tac,match", [
    (np.array([], dtype=np.int64), np.array([0]), "rgb: empty"),
    (np.array([0]), np.array([], dtype=np.int64), "tactile_right: empty"),
    (np.array([0.5]), np.array([0]), "integer"),
])
def test_bad_streams_raise_naming_the_stream(rgb, tac, match):
    with pytest.raises(ValueError, match=match):
        pair(rgb, {"right": tac}, max_skew_ns=MS)


def test_nearest_ties_go_to_earlier():
    np.testing.assert_array_equal(nearest(np.array([0, 10]), np.array([5, -3, 11])), [0, 0, 1])


def test_lag_decision_shifts_tactile_onto_the_rgb_clock():
    from htdata.source.lag import LagDecision

    t_rgb = np.arange(60, dtype=np.int64) * 33_333_333
    t_tac = np.arange(0, 2_000 * MS, 10 * MS, dtype=np.int64) + 150 * MS   # glove stamps 150 ms late
    plain = pair(t_rgb, {"right": t_tac}, max_skew_ns=6 * MS)
    assert "lag" not in plain.report and plain.report["drop_reasons"] == {"tactile_out_of_range:right": 5}
    applied = LagDecision("fixed", 150 * MS, True, "fixed")
    r = pair(t_rgb, {"right": t_tac}, max_skew_ns=6 * MS, lag=applied)
    assert not r.dropped and r.report["lag"] == applied.to_dict() and r.report["lag"]["lag_ms"] == 150.0
    np.testing.assert_array_equal(r.t_tactile_ns["right"], t_tac[r.tactile_index["right"]] - 150 * MS)
    assert np.all(np.abs(r.skew_ns["right"]) <= 5 * MS)
    declined = LagDecision("estimate", 0, False, "not applied: no contact changes")
    d = pair(t_rgb, {"right": t_tac}, max_skew_ns=6 * MS, lag=declined)
    np.testing.assert_array_equal(d.tactile_index["right"], plain.tactile_index["right"])
    assert d.report["lag"] == {"mode": "estimate", "lag_ms": None, "applied": False,
                               "reason": "not applied: no contact changes"}
    assert d.report["warnings"] == ["tactile-video lag not applied: no contact changes"]
    assert r.report["warnings"] == []
