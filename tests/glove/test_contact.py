"""Contact per glove hand from its calibration (htdata/glove/contact.py), in stats and trim --idle, on the raw-count glove."""

import numpy as np
import pytest

from htdata.glove.contact import MIN_AREA_TAXELS, OLD_RULE, min_area, rule_for
from htdata.read.itemoptions import ItemOptions
from htdata.synthetic.rawglove import CLIPS, FULL_SCALE, corpus_clips, glove_layout, write_rawglove

STEP = {"convention": "direct", "max": FULL_SCALE, "step": 1}


def test_a_flickering_handful_is_not_contact_under_a_calibrated_rule():
    x = np.zeros((10, 700), np.float32)
    x[:, :2] = 0.03                               # two taxels above 0.02: the old rule calls every frame contact
    x[5, 100:140] = 0.2                           # a press of 40 taxels in frame 5
    rule = rule_for({"noise_k": 3.0, "noise_floor": 0.0, "max_value": FULL_SCALE}, STEP, 169)
    assert rule.basis == "calibrated" and rule.min_taxels == MIN_AREA_TAXELS
    assert min_area(580) == 6 and min_area(100) == 3
    assert rule.level == pytest.approx(2 / FULL_SCALE)       # two quantisation steps above the floor
    assert rule.frames(x).tolist() == [i == 5 for i in range(10)]
    assert OLD_RULE.frames(x).all()


def test_the_press_level_is_the_glove_s_own_where_its_layout_declares_it():
    """`value.press` (raw units) sets the least rise that is a press; without it 1.5% of full scale."""
    cal = {"noise_k": 5.0, "noise_floor": 0.0, "max_value": FULL_SCALE, "scale": 2.0}
    default = rule_for(cal, STEP, 700)
    half = rule_for(cal, {**STEP, "press": 0.0075 * FULL_SCALE}, 700)
    assert default.press == pytest.approx(0.015 * 2.0) and half.press == pytest.approx(0.0075 * 2.0)
    x = np.zeros((3, 700), np.float32)
    x[1, :10] = 0.02                               # 10 taxels 1% of full scale (x scale 2) above rest
    x[2, :10] = 0.04
    floor = np.zeros(700, np.float32)              # the press counts from the floor-free rest
    assert default.frames(x, floor).tolist() == [False, False, True]
    assert half.frames(x, floor).tolist() == [False, True, True]
    assert "0.015 of full scale" in half.describe()


def test_a_calibration_without_a_floor_keeps_the_old_rule():
    assert rule_for({"noise_k": 0.0, "noise_floor": 0.0}, STEP) == OLD_RULE
    assert rule_for(None) == OLD_RULE
    assert "any taxel > 0.02" in OLD_RULE.describe()


def _truth_spans(margin):
    _, clips = corpus_clips(0)
    out = {}
    for c in clips:
        hit = np.zeros(c.n_frames, bool)
        for h in c.counts:
            hit |= c.truth_contact(h).sum(axis=1) >= min_area(int(glove_layout(h).live_mask.sum()))
        f = np.flatnonzero(hit)
        out[f"nat-{c.name}"] = (max(0, f[0] - margin), min(c.n_frames, f[-1] + 1 + margin))
    return out


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from tests.factories import ingest_cli

    tmp = tmp_path_factory.mktemp("contact")
    write_rawglove(tmp / "rg")
    out = {}
    for baseline in ("default", "rest_window"):      # default: no [normalise] table (each cell's own rest)
        sets = [] if baseline == "default" else [f"normalise.rawknit_{h}_32x32.{k}={v}" for h in ("left", "right")
                                                 for k, v in (("baseline", baseline), ("noise_k", 3))]
        args = ["--pipeline", "native", "--layouts", tmp / "rg" / "layouts"]
        for s in sets:
            args += ["--set", s]
        assert ingest_cli(*args, tmp / "rg", tmp / baseline) == 0
        out[baseline] = tmp / baseline
    return out


def test_stats_contact_follows_the_glove_truth(datasets):
    from htdata.inspect.stats import dataset_stats

    _, clips = corpus_clips(0)
    s = dataset_stats(datasets["default"], cache_dir=None)
    for g in s["gloves"]:
        area = min_area(int(glove_layout(g["hand"]).live_mask.sum()))
        truth = np.concatenate([c.truth_contact(g["hand"]).sum(axis=1) >= area for c in clips]).mean()
        assert abs(g["contact_fraction"] - truth) <= 0.10     # the README's target (counts truth: test_raw_count_rules)
        assert f"at least {area} taxels pressed more than 0.015 of full scale above rest" in g["contact_rule"]
        assert "more than 2 quantisation steps above their noise floor" in g["contact_rule"]
        assert g["contact_fraction_threshold"] is not None          # the old figure, beside it


def test_idle_trim_cuts_where_the_glove_rests(datasets):
    from htdata.curate.idle import IdleConfig, plan_idle
    from htdata.read.reader import DatasetReader

    truth = _truth_spans(margin=15)                  # 0.5 s at 30 fps
    with DatasetReader(datasets["default"]) as reader:
        cuts = {c.episode: c for c in plan_idle(reader, IdleConfig(), cache_dir=None)}
    for eid, (a, b) in truth.items():
        keep = cuts[eid].keep or range(0, cuts[eid].frames)
        assert abs(keep.start - a) <= 10 and abs(keep.stop - b) <= 10, (eid, keep, (a, b))


def test_taxel_health_comes_from_the_raw_rows_whatever_the_calibration(datasets):
    from htdata.inspect.stats import dataset_stats

    healths = [{g["hand"]: g["health"] for g in dataset_stats(datasets[b], cache_dir=None)["gloves"]}
               for b in ("default", "rest_window")]
    assert healths[0] == healths[1]
    assert healths[0]["right"]["basis"] == ["raw"]
    assert healths[0]["right"]["counts"]["stuck"] > 0 and healths[0]["right"]["counts"]["saturated"] > 0


def test_glove_only_dataset_says_why_paired_items_are_none(datasets):
    from htdata.read.torchdata import TactileFrameDataset

    with pytest.raises(ValueError, match='glove-only dataset.*frames="tactile"'):
        TactileFrameDataset(datasets["default"])
    tactile = TactileFrameDataset(datasets["default"], options=ItemOptions(frames="tactile"))
    assert len(tactile) == 2 * sum(n for _, n, _ in CLIPS)


def test_card_of_a_glove_only_dataset_states_its_contact_rule_and_draws_no_sync_plots(datasets, tmp_path):
    from htdata.inspect.card import write_card

    write_card(datasets["default"], tmp_path / "card.html")
    md = (tmp_path / "card.md").read_text()
    assert "glove-only episode(s) (no video) have none" in md
    assert "sync_skew" not in md and "more than 2 quantisation steps above their noise floor" in md
