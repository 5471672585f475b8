from types import SimpleNamespace

import numpy as np
import pytest

from htdata.glove.baselinefit import quietest_span
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import NormaliseConfig


def layout(h=4, w=4, dead=((0, 0),)):
    mask = np.ones((h, w), dtype=bool)
    for r, c in dead:
        mask[r, c] = False
    return SimpleNamespace(layout_id="test_4x4", live_mask=mask)


def test_inverted_formula_and_clip():
    n = Normaliser(NormaliseConfig(convention="inverted", max_value=3072), layout())
    raw = np.full((3, 4, 4), 3072, dtype=np.float32)
    raw[1] = 0          # saturated
    raw[2] = 1536
    raw[2, 1, 1] = 4095  # uncalibrated ADC above max -> clipped to 0
    v, ok = n.apply(raw)
    assert v.dtype == np.float32 and ok.all()
    assert np.all(v[0] == 0) and np.all(v[1] == 1)
    assert v[2, 2, 2] == pytest.approx(0.5) and v[2, 1, 1] == 0


def test_direct_and_scale():
    n = Normaliser(NormaliseConfig(convention="direct", max_value=2.0, scale=2.0), layout())
    v, _ = n.apply(np.full((1, 4, 4), 0.25, dtype=np.float32))
    assert np.allclose(v, 0.25)


def test_nan_inf_live_taxels_flag_frame_and_stay_non_finite():
    n = Normaliser(NormaliseConfig(), layout())
    raw = np.full((3, 4, 4), 0.5, dtype=np.float32)
    raw[:, 0, 0] = np.nan            # dead cell: ignored
    raw[1, 2, 2] = np.nan
    raw[2, 3, 3] = np.inf
    v, ok = n.apply(raw)
    np.testing.assert_array_equal(ok, [True, False, False])
    assert np.isnan(v[1, 2, 2]) and np.isnan(v[2, 3, 3])  # never silently 0
    assert np.all(v[0][layout().live_mask] == 0.5)


def test_all_nan_and_constant_maps():
    n = Normaliser(NormaliseConfig(), layout())
    v, ok = n.apply(np.full((2, 4, 4), np.nan, dtype=np.float32))
    assert not ok.any()
    v, ok = n.apply(np.zeros((2, 4, 4), dtype=np.float32))
    assert ok.all() and np.all(v == 0)


def test_first_frame_baseline_subtracts_and_clips_at_zero_without_nan():
    cfg = NormaliseConfig(convention="inverted", max_value=100, baseline="first_frame")
    n = Normaliser(cfg, layout())
    raw = np.full((3, 4, 4), 100, dtype=np.float32)
    raw[0, 1, 1] = 80      # baseline 0.2 at (1,1)
    raw[0, 2, 2] = 0       # saturated at rest: baseline 1 -> always 0 afterwards
    raw[1, 1, 1] = 50      # 0.5 - 0.2 = 0.3
    raw[2, 1, 1] = 100     # 0 - 0.2 -> clipped to 0
    with pytest.raises(RuntimeError, match="fit_baseline"):
        n.apply(raw)
    n.fit_baseline(raw[:1])
    v, ok = n.apply(raw)
    assert ok.all() and np.isfinite(v).all()
    assert v[1, 1, 1] == pytest.approx(0.3) and v[2, 1, 1] == 0 and np.all(v[:, 2, 2] == 0)


def test_rest_window_streaming_equals_whole():
    rng = np.random.default_rng(1)
    raw = rng.uniform(0, 1, size=(20, 4, 4)).astype(np.float32)
    raw[0, 3, 3] = np.nan  # non-finite sample in the rest window is ignored for the median
    cfg = NormaliseConfig(baseline="rest_window", rest_frames=5)
    whole = Normaliser(cfg, layout())
    whole.fit_baseline(raw[:8])
    vw, _ = whole.apply(raw)
    chunked = Normaliser(cfg, layout())
    chunked.fit_baseline(raw[:8])
    parts = [chunked.apply(raw[i:i + 7])[0] for i in range(0, 20, 7)]
    np.testing.assert_array_equal(np.concatenate(parts), vw)
    np.testing.assert_allclose(whole.baseline[1, 1], np.median(raw[:5, 1, 1]), rtol=1e-6)
    np.testing.assert_allclose(whole.baseline[3, 3], np.median(raw[1:5, 3, 3]), rtol=1e-6)


def test_baseline_taxel_never_finite_gets_zero():
    n = Normaliser(NormaliseConfig(baseline="first_frame"), layout())
    first = np.full((1, 4, 4), 0.1, dtype=np.float32)
    first[0, 2, 3] = np.nan
    base = n.fit_baseline(first)
    assert base[2, 3] == 0 and np.isfinite(base).all()


def test_strict_mode_rejects_out_of_range_naming_frame():
    n = Normaliser(NormaliseConfig(clip=False), layout())
    raw = np.full((2, 4, 4), 0.5, dtype=np.float32)
    raw[1, 2, 2] = 1.5
    with pytest.raises(ValueError, match="frame 1"):
        n.apply(raw)


def test_float16_limits_do_not_overflow_to_nan():
    n = Normaliser(NormaliseConfig(convention="inverted", max_value=65504.0), layout())
    raw = np.array([[[65504.0] * 4] * 4, [[0.0] * 4] * 4], dtype=np.float16)
    v, ok = n.apply(raw)
    assert ok.all() and np.all(v[0] == 0) and np.all(v[1] == 1)


def test_wrong_grid_shape_is_a_clear_error():
    n = Normaliser(NormaliseConfig(), layout())
    with pytest.raises(ValueError, match=r"test_4x4.*\(T,4,4\)"):
        n.apply(np.zeros((2, 16, 16), dtype=np.float32))


@pytest.mark.parametrize("kwargs,match", [
    ({"max_value": 0}, "max_value"), ({"max_value": -1}, "max_value"),
    ({"max_value": float("nan")}, "max_value"), ({"convention": "log"}, "convention"),
    ({"baseline": "median"}, "baseline"), ({"rest_frames": 0}, "rest_frames"),
    ({"scale": 0}, "scale"), ({"clip": "yes"}, "clip"),
])
def test_validate_rejects(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NormaliseConfig(**kwargs).validate()


def test_from_layout_value():
    cfg = NormaliseConfig.from_layout_value({"convention": "inverted", "max": 3072})
    assert cfg.convention == "inverted" and cfg.max_value == 3072.0
    # counts falling with pressure are raw counts too (issue 43): the raw-count default, as for a direct glove
    assert cfg.baseline == "drift" and cfg.noise_k == 5.0
    assert NormaliseConfig.from_layout_value({"convention": "direct", "max": 1.0}).baseline == "none"
    raw = NormaliseConfig.from_layout_value({"convention": "direct", "max": 1023, "step": 1})
    assert raw.baseline == "drift" and raw.noise_k == 5.0          # raw counts rest far above 0: each cell's own rest
    assert raw.baseline_percentile == 10.0 and raw.drift_window_s == 60.0


def test_noise_floor_is_estimated_from_the_whole_episode_rest_not_one_window():
    # a taxel glove resting 10 s: the quietest second is flat (spread 0), the rest level wanders +-4 counts
    rng = np.random.default_rng(4)
    T = 300
    t = np.arange(T)
    wander = 4.0 * np.sin(2 * np.pi * t / 200.0)[:, None, None] * rng.uniform(0.5, 1.0, (1, 4, 4))
    raw = np.round(550 + wander + rng.normal(0, 0.3, (T, 4, 4))).astype(np.float32)
    raw[240:270, 2, 2] += 60                                      # one press
    lay = SimpleNamespace(layout_id="test_4x4", live_mask=np.ones((4, 4), bool), value={"step": 1})
    n = Normaliser(NormaliseConfig(convention="direct", max_value=1023, baseline="quietest", noise_k=3), lay)
    n.fit_episode(raw, fps=30.0)
    v, _ = n.apply(raw)
    rest = np.ones(v.shape, bool)
    rest[240:270, 2, 2] = False
    assert (v[rest] > 0).mean() < 0.02                            # the wander reads 0
    assert (v[245:265, 2, 2] > 0).all()                           # the press survives the floor
    # one window's spread (the quietest second) would leave the wander lit: the floor is wider than that
    quiet = raw[quietest_span(raw / 1023, n.live_mask, n.cfg.rest_seconds, 30.0)] / 1023
    one_window = 3 * 1.4826 * np.median(np.abs(quiet - np.median(quiet, axis=0)), axis=0)
    assert (n.floor > one_window + 1.5 / 1023).mean() > 0.5


@pytest.mark.parametrize("noise_k, noise_floor, floored", [(0.0, 0.0, False), (3.0, 0.0, True), (0.0, 0.05, True)])
def test_one_noise_floor_test_for_the_normaliser_and_the_contact_rule(noise_k, noise_floor, floored):
    """`has_noise_floor` decides it for the Normaliser (subtract the floor, never below one step) and the
    contact rule read from a manifest entry alike."""
    from htdata.glove.contact import rule_for
    from htdata.glove.normaliseconfig import has_noise_floor

    cfg = NormaliseConfig(max_value=10.0, baseline="rest_window" if noise_k else "none", noise_k=noise_k,
                          noise_floor=noise_floor).validate()
    assert has_noise_floor(noise_k, noise_floor) is cfg.has_noise_floor is floored
    lay = SimpleNamespace(layout_id="test_4x4", live_mask=np.ones((4, 4), bool), value={"step": 1, "max": 10})
    n = Normaliser(cfg, lay)
    assert n.min_floor == pytest.approx(0.1 if floored else 0.0)          # one step (1 / max_value) when floored
    if cfg.baseline == "none":
        v, _ = n.apply(np.full((1, 4, 4), 5.0, np.float32))
        assert v[0, 1, 1] == pytest.approx(0.4 if floored else 0.5)          # 0.5 - max(0.05, one step)
    assert rule_for(cfg.to_dict(), lay.value, 16).basis == ("calibrated" if floored else "threshold")


def test_a_calibration_record_is_read_through_its_config():
    """validate/, inspect/ and curate/ read a manifest calibration entry as NormaliseConfig.from_record and ask it
    the rules (tests/project/test_glove_rule_owner.py refuses the entry's keys read there)."""
    entry = {"layout": "g", "convention": "inverted", "max_value": 3072, "baseline": "none", "clip": True,
             "scale": 1.0, "noise_floor": 0.0, "noise_k": 0.0, "rest_frames": 10, "from": "pipeline 'p'",
             "fitted_per_episode": False, "revision": 1}
    cfg = NormaliseConfig.from_record(entry)
    assert (cfg.convention, cfg.max_value, cfg.baseline) == ("inverted", 3072, "none")
    assert cfg.raw_counts and not cfg.subtracts_rest and cfg.validate() is cfg
    assert NormaliseConfig.from_record({**entry, "baseline": "drift", "noise_k": 5.0}).subtracts_rest
    assert NormaliseConfig.from_record({**entry, "taxel_calibration_sha256": "ab" * 32}).subtracts_rest
    assert not NormaliseConfig.from_record(None).raw_counts and NormaliseConfig.from_record({}) == NormaliseConfig()
