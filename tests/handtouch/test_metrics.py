import math

import numpy as np
import pytest
import torch

from handtouch.bench.metrics import REGIONS, MapMetrics, TrackMetrics, frame_scores


def _b(*maps):
    return torch.tensor(np.array(maps, dtype=np.float32))[:, None]


def test_hand_computed_rmse_and_ciou():
    target = _b([[0.5, 1.0], [0.0, 0.2]])
    pred = _b([[0.25, 1.0], [0.1, 0.9]])
    region = _b([[1, 1], [1, 0]])          # the 0.2/0.9 pixel is not covered
    s = frame_scores(pred, target, region)
    # squared errors 0.0625, 0, 0.01 over 3 pixels
    assert s.rmse.item() == pytest.approx(math.sqrt(0.0725 / 3))
    # min: 0.25 + 1 + 0 ; max: 0.5 + 1 + 0.1
    assert s.ciou.item() == pytest.approx(1.25 / 1.6)


def test_prediction_clamped_for_ciou_but_not_for_rmse():
    target = _b([[1.0, 0.0]])
    pred = _b([[1.5, -0.5]])
    region = _b([[1, 1]])
    s = frame_scores(pred, target, region)
    assert s.ciou.item() == pytest.approx(1.0)            # clamps to [1, 0] == target
    assert s.rmse.item() == pytest.approx(0.5)            # raw errors 0.5 and 0.5


def test_both_zero_is_one_and_empty_region_is_skipped():
    z = _b([[0.0, 0.0]], [[0.0, 0.0]])
    region = _b([[1, 1]], [[0, 0]])
    s = frame_scores(z, z, region)
    assert s.ciou[0].item() == 1.0 and s.rmse[0].item() == 0.0
    assert math.isnan(s.ciou[1].item())                   # marks "not scored", never averaged
    m = MapMetrics()
    m.add(s)
    r = m.result()
    assert r["frames"] == 1 and r["skipped"] == 1
    assert r["ciou"] == 1.0 and r["ciou_pooled"] == 1.0 and r["rmse"] == 0.0


def test_no_frames_gives_none_not_nan():
    m = MapMetrics()
    m.update(_b([[0.3]]), _b([[0.1]]), _b([[0]]))
    r = m.result()
    assert r["rmse"] is None and r["ciou"] is None and r["skipped"] == 1


def test_predicted_contact_on_empty_target_scores_zero():
    s = frame_scores(_b([[0.4, 0.0]]), _b([[0.0, 0.0]]), _b([[1, 1]]))
    assert s.ciou.item() == 0.0


def test_per_frame_mean_vs_pooled():
    target = _b([[1.0, 1.0]], [[0.1, 0.0]])
    pred = _b([[1.0, 1.0]], [[0.0, 0.0]])
    region = torch.ones_like(target)
    m = MapMetrics()
    m.update(pred[:1], target[:1], region[:1])
    m.update(pred[1:], target[1:], region[1:])           # accumulates across batches
    r = m.result()
    assert r["ciou"] == pytest.approx((1.0 + 0.0) / 2)
    assert r["ciou_pooled"] == pytest.approx(2.0 / 2.1)
    assert r["rmse"] == pytest.approx((0.0 + math.sqrt(0.01 / 2)) / 2)
    assert r["rmse_pooled"] == pytest.approx(math.sqrt(0.01 / 4))


def test_rejects_non_finite_and_shape_mismatch():
    t = _b([[0.1, 0.2]])
    with pytest.raises(ValueError, match="non-finite.*\\[0\\]"):
        frame_scores(_b([[np.nan, 0.0]]), t, torch.ones_like(t), name="prediction")
    with pytest.raises(ValueError, match="target"):
        frame_scores(t, _b([[np.inf, 0.0]]), torch.ones_like(t))
    with pytest.raises(ValueError, match="shapes differ"):
        frame_scores(_b([[0.1, 0.2, 0.3]]), t, torch.ones_like(t))


def test_float16_inputs_and_extremes():
    target = torch.tensor([[[[65504.0, 0.0]]]], dtype=torch.float16).clamp(max=1.0)
    pred = torch.tensor([[[[6e-8, 1.0]]]], dtype=torch.float16)
    s = frame_scores(pred, target, torch.ones(1, 1, 1, 2))
    assert math.isfinite(s.rmse.item()) and math.isfinite(s.ciou.item())
    assert s.ciou.item() == pytest.approx(float(pred[0, 0, 0, 0]) / 2.0, rel=1e-3)


def test_track_metrics_covered_and_whole_canvas_hand_computed():
    target = _b([[0.5, 1.0], [0.0, 0.2]])
    pred = _b([[0.25, 1.0], [0.1, 0.9]])
    coverage = _b([[1, 1], [1, 0]])          # the 0.2/0.9 pixel has no sensor
    mask = _b([[0, 1], [0, 1]])              # hidden part: the right column
    m = TrackMetrics(holes=True)
    m.update(pred, target, coverage, mask)
    r = m.result()
    assert tuple(r) == REGIONS
    assert r["f_covered"]["rmse"] == pytest.approx(math.sqrt(0.0725 / 3))
    assert r["f_full"]["rmse"] == pytest.approx(math.sqrt((0.0725 + 0.49) / 4))
    assert r["f_full"]["ciou"] == pytest.approx((1.25 + 0.2) / (1.6 + 0.9))
    assert r["h_covered"]["rmse"] == 0.0 and r["h_covered"]["ciou"] == 1.0       # only the 1.0/1.0 pixel
    assert r["h_full"]["rmse"] == pytest.approx(math.sqrt(0.49 / 2))
    assert r["h_full"]["ciou"] == pytest.approx((1.0 + 0.2) / (1.0 + 0.9))


def test_track_metrics_empty_regions_and_all_zero_frames():
    z = _b([[0.0, 0.0]], [[0.0, 0.0]])
    coverage = _b([[0, 0]], [[1, 0]])                     # frame 0: no covered pixel
    mask = _b([[0, 0]], [[0, 0]])                         # no hidden part in either frame
    m = TrackMetrics(holes=True)
    m.update(z, z, coverage, mask)
    r = m.result()
    assert r["f_covered"]["frames"] == 1 and r["f_covered"]["skipped"] == 1
    assert r["f_full"]["frames"] == 2 and r["f_full"]["skipped"] == 0          # the canvas is never empty
    assert r["f_full"]["ciou"] == 1.0 and r["f_full"]["rmse"] == 0.0           # 0/0 contact: a right "no contact"
    for region in ("h_covered", "h_full"):                                     # nothing hidden: null, never NaN
        assert r[region]["rmse"] is None and r[region]["ciou"] is None and r[region]["skipped"] == 2
    assert set(TrackMetrics().result()) == {"f_covered", "f_full"}
    assert TrackMetrics().result()["f_full"]["rmse"] is None                   # no frame at all


def test_track_metrics_mask_matches_holes_flag():
    t = _b([[0.1, 0.2]])
    with pytest.raises(ValueError, match="mask"):
        TrackMetrics().update(t, t, torch.ones_like(t), torch.ones_like(t))
    with pytest.raises(ValueError, match="mask"):
        TrackMetrics(holes=True).update(t, t, torch.ones_like(t))
