"""The sample world's raw-count glove, and the baselines chosen by activity / following drift measured on it."""

import json

import numpy as np
import pytest

from htdata.benchmarks.rawglove import config_for, normalise_clip, score
from htdata.glove.baselinefit import quietest_span
from htdata.glove.calibration import calibration_id, episode_normaliser, fit_record
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.synthetic.rawglove import (
    FULL_SCALE,
    REST,
    SATURATE,
    TRUTH_LEVEL,
    GloveUnit,
    corpus_clips,
    glove_layout,
    make_clip,
    write_rawglove,
)


@pytest.fixture(scope="module")
def corpus():
    return corpus_clips(0)


def _clip(clips, start):
    return next(c for c in clips if c.start == start and c.task == "pour")


def test_counts_look_like_the_real_glove(corpus):
    units, clips = corpus
    clip = _clip(clips, "rest")
    for hand, counts in clip.counts.items():
        assert counts.dtype == np.float16 and not np.array_equal(counts, np.round(counts))   # half counts too
        live = glove_layout(hand).live_mask
        first = counts[:10].astype(np.float32)[:, live]
        assert abs(float(np.median(first)) - REST[hand]) < 3                             # rest ~557 / ~566
        offsets = np.median(first, axis=0)
        assert np.ptp(offsets[offsets < 700]) > 15                                       # per-cell offsets
        assert float(counts.max()) == SATURATE                                           # cells saturate
        # hardly any fast noise: a third or more of the taxels have zero robust spread over 10 frames
        mad = np.median(np.abs(first - np.median(first, axis=0)), axis=0)
        assert 0.2 < float((mad == 0).mean()) < 0.7
    u = units["right"]
    raw = clip.counts["right"].astype(np.float32)
    (r, c), = u.faults.cells["saturating"][:1]
    assert np.all(raw[:, r, c] == SATURATE)
    for r, c in u.faults.cells["stuck"]:
        assert np.ptp(raw[:, r, c]) == 0 and raw[0, r, c] > 700
    for r, c in u.faults.cells["dead"]:
        assert np.ptp(raw[:, r, c]) == 0


def test_every_cell_wanders_slowly_at_rest_like_the_real_glove(corpus):
    from htdata.glove.activity import CellActivity

    units, clips = corpus
    clip = _clip(clips, "rest")
    lay = glove_layout("left")
    gaps = ~np.asarray(lay.live_mask) & ~np.asarray(lay.unmapped_mask)   # the gaps (listed as unused cells)
    gaps[:, units["left"].faults.crosstalk_cols] = False
    quiet = gaps & (units["left"].noise < 1)
    act = CellActivity(lay.grid)
    act.add(clip.counts["left"])
    # a gap cell carries no sensor, yet its rest level wanders several counts over a clip, far more than its
    # frame-to-frame noise (the real glove: gaps range 4-6 counts over 150-1000 frames, fast noise 0.15)
    assert 3 <= float(np.median(act.range[quiet])) <= 8
    assert float(np.median(act.cell_wander()[quiet])) >= 3 * float(np.median(act.cell_noise[quiet]))


def test_clip_starts_and_determinism(corpus):
    _, clips = corpus
    rest, mid = _clip(clips, "rest"), _clip(clips, "mid_grasp")
    assert not rest.truth_contact("right")[0].any()
    assert rest.truth_contact("right").any()
    assert mid.truth_contact("right")[0].sum() >= 15           # already gripping in frame 0
    assert not mid.truth_contact("right")[-1].any()            # and let go before the end
    again = corpus_clips(0)[1]
    assert all(np.array_equal(a.counts[h], b.counts[h]) for a, b in zip(clips, again) for h in a.counts)


def test_write_rawglove_is_a_glove_only_native_corpus(tmp_path):
    out = write_rawglove(tmp_path / "rg")
    assert out["clips"] == 5
    rec = json.loads((tmp_path / "rg" / "rawknit_00_slice_rest" / "recording.json").read_text())
    assert "video" not in rec and set(rec["hands"]) == {"left", "right"}
    truth = json.loads((tmp_path / "rg" / "truth.json").read_text())
    assert truth["clips"]["rawknit_00_slice_rest"]["working_hand"] == "right"
    assert truth["faults"]["right"]["crosstalk_cols"] == [31]
    with np.load(tmp_path / "rg" / "rawknit_00_slice_rest" / "tactile_left.npz") as z:
        assert z["values"].dtype == np.float16 and z["values"].shape[1:] == (32, 32)
    assert sorted(p.name for p in (tmp_path / "rg" / "layouts").iterdir()) == \
        ["rawknit_left_32x32.calibration.npz", "rawknit_left_32x32.json",
         "rawknit_right_32x32.calibration.npz", "rawknit_right_32x32.json"]


def _rates(values, clip, hand):
    c = score(values, clip.pressure[hand][:, glove_layout(hand).live_mask])
    return c["tp"] / (c["tp"] + c["fn"]), c["rest_above_0"] / c["rest"], c["tp"] / max(c["tp"] + c["fp"], 1)


def test_a_grip_held_from_the_first_frame_is_kept_by_the_activity_baselines_not_the_rest_window(corpus):
    """Measured as on the real glove (its counts alone: htdata/benchmarks/realglove.py), at the clip start."""
    from htdata.benchmarks.realglove import HandTruth, hand_counts, normalised
    from htdata.glove.rasterise import Rasteriser

    _, clips = corpus
    mid = _clip(clips, "mid_grasp")
    layout = glove_layout("right")
    truth = HandTruth.of(mid.counts["right"], layout.live_mask)
    assert truth.mid_grasp

    def kept_at_start(baseline):
        cfg = config_for(baseline, True)
        c = hand_counts(truth, normalised(mid.counts["right"], layout, cfg, mid.fps), layout, Rasteriser(layout))
        return c["start_kept"] / c["start_pressed"]

    assert kept_at_start("rest_window") < 0.3            # the first 10 frames absorb the grip
    assert kept_at_start("default") >= 0.9 and kept_at_start("percentile") >= 0.9


def test_quietest_span_is_in_seconds():
    lay = glove_layout("right")
    raw = np.full((300, 32, 32), 600.0, np.float32)
    raw[:150] += 50.0                      # pressed for the first 5 s at 30 fps
    raw[200:230] -= 1.0                    # the quietest second: frames 200..229
    n = Normaliser(NormaliseConfig(convention="direct", max_value=FULL_SCALE, baseline="quietest",
                                   rest_seconds=1.0), lay)
    span = quietest_span(n.to_unit(raw), n.live_mask, n.cfg.rest_seconds, fps=30.0)
    assert (span.start, span.stop) == (200, 230)
    span = quietest_span(n.to_unit(raw), n.live_mask, n.cfg.rest_seconds, fps=10.0)  # 1 s = 10 frames at 10 fps
    assert span.stop - span.start == 10 and 200 <= span.start <= 220


def test_noise_floor_never_below_the_quantisation_step():
    lay = glove_layout("right")
    step = float(lay.value["step"])                          # the glove's float16 counts: 0.25-count steps
    raw = np.full((40, 32, 32), 550.0, np.float32)          # no spread at all: k x 0 = 0
    n = Normaliser(config_for("rest_window", True), lay)
    n.fit_baseline(raw)
    assert np.all(n.floor[lay.live_mask] >= np.float32(step / FULL_SCALE))   # one step
    raw[5, 3, 3] += step                                     # one step of flicker reads 0
    v, _ = n.apply(raw)
    assert v[5, 3, 3] == 0
    raw[5, 3, 3] += step                                     # two steps do not
    assert n.apply(raw)[0][5, 3, 3] > 0
    # without a floor (noise_k = 0, noise_floor = 0) nothing changes: one step reads above 0
    plain = Normaliser(config_for("rest_window", False), lay)
    plain.fit_baseline(raw[:10])
    raw[6, 3, 3] += step
    assert plain.apply(raw)[0][6, 3, 3] > 0


def test_drift_baseline_follows_a_ten_minute_drift():
    unit = GloveUnit.make("right", 3)
    clip = make_clip("drift", "power_grasp", 18000, "rest", 3, {"right": unit})
    live = glove_layout("right").live_mask
    tail = slice(18000 - 900, 18000)

    def rest_above(baseline):
        v = normalise_clip(clip, "right", config_for(baseline, True))[tail]
        return score(v, clip.pressure["right"][tail][:, live])["rest_above_0"] / live.sum() / 900

    with_drift, without = rest_above("default"), rest_above("rest_window")   # default: 60 s windows per cell
    assert without > 0.3 and with_drift < 0.05


def test_drift_knots_round_trip_through_the_episode_record():
    lay = glove_layout("left")
    unit = GloveUnit.make("left", 1)
    clip = make_clip("d", "power_grasp", 3000, "rest", 1, {"left": unit})
    cfg = NormaliseConfig(convention="direct", max_value=FULL_SCALE, baseline="drift", noise_k=3.0,
                          drift_window_s=20.0)
    n = Normaliser(cfg, lay)
    raw = clip.counts["left"].astype(np.float32)
    rows = np.arange(len(raw))
    n.fit_episode(raw, 30.0, rows)
    assert n.baseline.shape == (5, 32, 32)
    cal = calibration_id(lay.layout_id, cfg)
    manifest = {"calibrations": {cal: {"layout": lay.layout_id, **cfg.to_dict()}}}
    episode = {"episode_id": "e", "calibration": {"left": cal}, "calibration_fit": {"left": fit_record(n)}}
    back = episode_normaliser(json.loads(json.dumps(manifest)), json.loads(json.dumps(episode)), "left", lay)
    assert np.array_equal(back.apply(raw[100:200], rows=rows[100:200])[0], n.apply(raw[100:200], rows=rows[100:200])[0])
    with pytest.raises(ValueError, match="needs the raw rows"):
        n.apply(raw[:5])


def test_default_settings_keep_their_calibration_ids():
    # the new fields at their defaults leave to_dict (and so every existing calibration id) as it was
    assert set(NormaliseConfig().to_dict()) == {"convention", "max_value", "baseline", "rest_frames", "clip",
                                                "scale", "noise_floor", "noise_k"}
    assert "rest_seconds" in NormaliseConfig(baseline="quietest", rest_seconds=2.0).to_dict()


@pytest.mark.parametrize("kwargs, match", [
    ({"baseline": "quietest", "rest_seconds": 0.0}, "rest_seconds"),
    ({"baseline": "percentile", "baseline_percentile": 120.0}, "baseline_percentile"),
    ({"baseline": "drift", "drift_window_s": -1.0}, "drift_window_s"),
    ({"baseline": "first_frame", "noise_k": 3.0}, "noise_k needs"),
])
def test_validate_rejects_activity_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NormaliseConfig(**kwargs).validate()


def test_truth_level_is_stated():
    assert 0 < TRUTH_LEVEL < 0.2


def _ingest_rawglove(tmp_path, pipeline_name: str, tables: str):
    """The raw-count glove corpus under tmp_path/rg, ingested with a native pipeline of these TOML tables;
    returns (pipeline path, dataset path)."""
    from tests.factories import ingest_cli

    write_rawglove(tmp_path / "rg")
    pipe = tmp_path / pipeline_name
    pipe.write_text('name = "rawknit"\n[adapter]\nname = "native"\n[adapter.params]\n' + tables)
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", pipe, "--layouts", tmp_path / "rg" / "layouts", tmp_path / "rg", out) == 0
    return pipe, out


def test_ingest_stats_and_renormalise_with_the_activity_baselines(tmp_path):
    from htdata.inspect.stats import dataset_stats
    from htdata.read.reader import DatasetReader

    pipe, out = _ingest_rawglove(tmp_path, "rawknit.toml",
                                 '[tactile]\nkeep_raw = true\nmaps = "stored"\n'
                                 '[normalise.rawknit_left_32x32]\nbaseline = "quietest"\nnoise_k = 3\n'
                                 '[normalise.rawknit_right_32x32]\nbaseline = "drift"\ndrift_window_s = 2\nnoise_k = 3\n')
    with DatasetReader(out) as reader:
        cals = reader.manifest["calibrations"]
        assert sorted(e["baseline"] for e in cals.values()) == ["drift", "quietest"]
        first = [reader.decoded(i)["tactile"]["right"] for i in (0, 150, 400)]
    stats = dataset_stats(out, cache_dir=None)
    assert all(g["frames_from_raw"] == g["frames"] for g in stats["gloves"])   # drift values from the raw rows
    # renormalise away and back: the drift fit from the stored rows reproduces the ingest's maps
    from htdata.cli import main
    layout = "normalise.rawknit_right_32x32"
    assert main(["renormalise", str(out), "--pipeline", str(pipe), "--set", f"{layout}.baseline=percentile"]) == 0
    assert main(["renormalise", str(out), "--pipeline", str(pipe), "--set", f"{layout}.baseline=drift",
                 "--set", f"{layout}.drift_window_s=2"]) == 0
    with DatasetReader(out) as reader:
        assert reader.version == 3
        again = [reader.decoded(i)["tactile"]["right"] for i in (0, 150, 400)]
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    # the loaders serve maps rendered from the raw rows (drift knots by source row): validate finds them equal
    from htdata.validate import validate_dataset
    report = validate_dataset(out, deep=True)
    assert report["checks"]["content"]["checked"]["served_maps"] > 0
    assert "served_map" not in report["checks"]["content"]["failure_counts"]


def test_out_of_range_warnings_reach_stderr(tmp_path, capsys):
    from tests.factories import ingest_cli

    write_rawglove(tmp_path / "rg")
    # max_value set to the range above rest (472) instead of full scale (1023): every frame is out of range
    rc = ingest_cli("--pipeline", "native", "--layouts", tmp_path / "rg" / "layouts",
                    "--set", "normalise.rawknit_right_32x32.max_value=472",
                    "--set", "normalise.rawknit_left_32x32.baseline=none", tmp_path / "rg", tmp_path / "ds")
    assert rc == 0
    err = capsys.readouterr().err
    assert "episode nat-rawknit_00_slice_rest: warning: right hand: 450 of 450 frames" in err
    assert "outside [0, 472]" in err and "FULL-SCALE" in err
    # baseline "none" on a raw-count glove reads its rest as pressure: one line per episode names the setting
    line = next(x for x in err.splitlines() if "nat-rawknit_00_slice_rest" in x and "covered pixels" in x)
    assert "left hand (layout rawknit_left_32x32): rest level 5" in line and "of 1023" in line
    assert "read >= 0.5" in line and 'drop the baseline line from [normalise.rawknit_left_32x32]' in line
    assert "right hand (layout rawknit_right_32x32): rest level" not in err     # its default: drift
    from htdata.read.reader import DatasetReader
    with DatasetReader(tmp_path / "ds") as reader:
        assert sorted(e["baseline"] for e in reader.manifest["calibrations"].values()) == ["drift", "none"]
    # and validate fails it, naming the setting (the right hand, on its default, passes)
    from htdata.validate import validate_dataset
    report = validate_dataset(tmp_path / "ds")
    failures = [f for f in report["checks"]["sensors"]["failures"] if f["what"] == "rest_level"]
    assert not report["ok"] and len(failures) == 5 and {f["hand"] for f in failures} == {"left"}
    assert "rest level 5" in failures[0]["message"] and "of 1023" in failures[0]["message"]
    assert "drop the baseline line from [normalise.rawknit_left_32x32]" in failures[0]["message"]


def test_taxel_calibration_file_formula_and_errors(tmp_path):
    lay = glove_layout("right")
    offset = np.full((32, 32), 550.0, np.float32)
    offset[3, 3] = 600.0
    gain = np.ones((32, 32), np.float32)
    gain[3, 3] = 0.5
    path = tmp_path / "cal.npz"
    np.savez(path, offset=offset, gain=gain)
    cfg = NormaliseConfig(convention="direct", max_value=FULL_SCALE, taxel_calibration=str(path),
                          taxel_calibration_sha256="x" * 64)
    n = Normaliser(cfg, lay)
    raw = np.full((1, 32, 32), 652.3, np.float32)
    v, _ = n.apply(raw)
    assert v[0, 0, 0] == pytest.approx(102.3 / FULL_SCALE, rel=1e-5)            # (raw - offset) * gain / max
    assert v[0, 3, 3] == pytest.approx(52.3 * 0.5 / FULL_SCALE, rel=1e-5)
    assert set(n.fitted()) == {"baseline", "noise_floor", "offset", "gain"}
    np.savez(tmp_path / "bad.npz", offset=offset[:8], gain=gain)
    with pytest.raises(ValueError, match="bad.npz: offset has shape"):
        Normaliser(NormaliseConfig(taxel_calibration=str(tmp_path / "bad.npz")), lay)
    np.savez(tmp_path / "zero.npz", offset=offset, gain=gain * 0)
    with pytest.raises(ValueError, match="gain must be > 0"):
        Normaliser(NormaliseConfig(taxel_calibration=str(tmp_path / "zero.npz")), lay)


def test_ingest_with_a_taxel_calibration_file_and_renormalise_from_the_record(tmp_path, capsys):
    from htdata.cli import main
    from htdata.inspect.stats import dataset_stats
    from htdata.read.reader import DatasetReader

    pipe, out = _ingest_rawglove(tmp_path, "rg/rawknit_cal.toml",   # the calibration path is relative to this file
                                 '[normalise.rawknit_right_32x32]\n'
                                 'taxel_calibration = "layouts/rawknit_right_32x32.calibration.npz"\n'
                                 'baseline = "quietest"\nnoise_k = 3\n')
    with DatasetReader(out) as reader:
        entry = next(e for e in reader.manifest["calibrations"].values() if e["layout"] == "rawknit_right_32x32")
        assert len(entry["taxel_calibration_sha256"]) == 64 and "taxel_calibration" not in entry
        assert "offset" in reader.episodes[0]["calibration_fit"]["right"]
        before = [reader.decoded(i)["tactile"]["right"] for i in (10, 120)]
    # --force: the same calibration, rebuilt from the record's offset and gain, gives the same maps
    assert main(["renormalise", str(out), "--pipeline", str(pipe), "--force"]) == 0
    with DatasetReader(out) as reader:
        assert all(np.array_equal(a, reader.decoded(i)["tactile"]["right"]) for a, i in zip(before, (10, 120)))
    # the dataset needs no copy of the file: stats from the raw rows restore offset and gain from the records
    (tmp_path / "rg" / "layouts" / "rawknit_right_32x32.calibration.npz").unlink()
    stats = dataset_stats(out, cache_dir=None)
    assert all(g["frames_from_raw"] == g["frames"] for g in stats["gloves"])
    right = next(g for g in stats["gloves"] if g["hand"] == "right")
    clips = corpus_clips(0)[1]                    # truth: frames with >= 7 pressed cells (issue 34's measure)
    truth = sum(int((c.truth_contact("right").sum(axis=1) >= 7).sum()) for c in clips) / sum(c.n_frames for c in clips)
    assert abs(right["contact_fraction"] - truth) <= 0.10
