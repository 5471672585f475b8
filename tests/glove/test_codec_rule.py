"""The tactile codec rule (htdata/glove/codecrule.py): smallest EXR codec keeping every glove's levels.

The rule runs twice in the code: the ingest resolves `[codec] tactile = "auto"`
with analytic max errors, the bench picks from errors and sizes measured on
maps. Here both run on maps rasterised from each shipped glove at its own
quantisation levels, and must agree; the levels themselves are checked to
round back exactly from the codec the rule picks and not from the one it
rejects.
"""

import numpy as np
import pytest

from htdata.benchmarks.codecs import codec_rows
from htdata.format.table import CodecSettings, decode_sample, encode_sample
from htdata.format.tactilecodec import decode_tactile, encode_tactile
from htdata.glove.codecrule import (
    ANALYTIC_MAX_ERROR,
    SIZE_ORDER,
    CodecChoice,
    GloveStep,
    codec_block,
    glove_step,
    pick_codec,
    resolve_codec,
)
from htdata.glove.codecsettings import CodecConfig
from htdata.glove.layouts import load_layout
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.glove.rasterise import Rasteriser
from htdata.ingest.pipeline import PipelineConfig, load_pipeline

OT, TA_L, TA_R = "opentouch_right_16x16", "touchanything_left_21x21", "touchanything_right_21x21"
LEVELS = {OT: 3072, TA_L: 255, TA_R: 255}     # source levels over [0, 1] after normalisation


def levelled(layout_id: str, frames: int = 6, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(maps (T,224,224), integer levels (T,H,W)): sparse contact at the glove's own quantisation levels."""
    layout = load_layout(layout_id)
    rng = np.random.default_rng(seed)
    n = LEVELS[layout_id]
    levels = rng.integers(0, n + 1, (frames, *layout.grid))
    levels[rng.random(levels.shape) < 0.6] = 0
    grids = (levels / n).astype(np.float32)
    return Rasteriser(layout, mode="nearest").render(grids), levels


def test_glove_steps_come_from_the_layout_value_block_and_normalisation():
    assert glove_step(load_layout(OT)).step == 1 / 3072
    assert glove_step(load_layout(TA_L)).step == glove_step(load_layout(TA_R)).step == 1 / 255
    scaled = glove_step(load_layout(OT), NormaliseConfig(convention="inverted", max_value=1024.0, scale=2.0))
    assert scaled.step == pytest.approx(2 / 1024) and "max_value 1024" in scaled.source
    layout = load_layout(OT)
    no_step = type(layout)(**{**layout.__dict__, "value": {"convention": "inverted", "max": 3072}})
    assert glove_step(no_step).step is None


def test_rule_picks_smallest_codec_keeping_every_glove():
    rows = [{"codec": "exr_float_zip", "max_error": 0.0, "bytes_per_frame": 5000.0},
            {"codec": "exr_half_zip", "max_error": 2.44e-4, "bytes_per_frame": 3400.0},
            {"codec": "exr_half_piz", "max_error": 2.44e-4, "bytes_per_frame": 13000.0},
            {"codec": "png16", "max_error": 7.6e-6, "bytes_per_frame": 100.0}]   # not storable: never picked
    coarse, fine = GloveStep("coarse", 1 / 255, "t"), GloveStep("fine", 1 / 3072, "t")
    assert pick_codec([coarse], rows)[0]["codec"] == "exr_half_zip"
    row, why = pick_codec([coarse, fine], rows)
    assert row["codec"] == "exr_float_zip" and "strictest glove fine" in why and "exr_half_zip would lose" in why
    assert pick_codec([GloveStep("unknown", None, "t")], rows)[0]["codec"] == "exr_float_zip"
    assert pick_codec([GloveStep("tiny", 1e-9, "t")], rows[1:])[0] is None


def test_resolve_codec_auto_explicit_and_kept_on_append():
    ot, ta = glove_step(load_layout(OT)), glove_step(load_layout(TA_L))
    assert resolve_codec("auto", "zip", [ta]).codec == "exr_half_zip"
    both = resolve_codec("auto", "piz", [ta, ot])
    assert (both.codec, both.chosen_by) == ("exr_float_piz", "rule") and OT in both.reason
    explicit = resolve_codec("exr_half", "zip", [ot, ta])
    assert explicit.chosen_by == "pipeline" and f"levels NOT kept for: {OT}" in explicit.reason
    kept = resolve_codec("auto", "zip", [ot], existing={"pixel_type": "half"})
    assert kept.pixel_type == "half" and kept.chosen_by == "dataset" and OT in kept.reason
    assert resolve_codec("auto", "zip", [ot], existing={"pixel_type": "float"}) == resolve_codec("auto", "zip", [ot])
    with pytest.raises(ValueError, match="codec"):
        resolve_codec("png16", "zip", [ot])


@pytest.mark.parametrize("gloves, expected", [((OT,), "exr_float_zip"), ((TA_L, TA_R), "exr_half_zip"),
                                               ((OT, TA_L, TA_R), "exr_float_zip")])
def test_code_default_equals_the_rule_on_measured_maps(gloves, expected):
    res = codec_rows({g: levelled(g, seed=i)[0] for i, g in enumerate(gloves)})
    assert res["default"] == res["code_default"] == expected, res["reason"]
    sizes = {r["codec"]: r["bytes_per_frame"] for r in res["rows"]}
    # SIZE_ORDER (what the ingest's analytic rule ranks by) holds on these maps
    assert [sizes[f"exr_{p}_zip"] for p in SIZE_ORDER] == sorted(sizes[f"exr_{p}_zip"] for p in SIZE_ORDER)
    measured = {r["codec"]: r["max_error"] for r in res["rows"]}
    assert measured["exr_half_zip"] <= ANALYTIC_MAX_ERROR["half"] and measured["exr_float_zip"] == 0.0


def test_levels_round_back_with_the_chosen_codec_only():
    maps, levels = levelled(OT, frames=4)
    layout = load_layout(OT)
    sampler = Rasteriser(layout, mode="nearest")
    live = layout.live_mask

    def back(pixel_type):
        decoded = np.stack([decode_tactile(encode_tactile(m, "zip", pixel_type=pixel_type)) for m in maps])
        return np.round(sampler.sample(decoded)[:, live] * 3072).astype(int)

    assert np.array_equal(back("float"), levels[:, live])
    assert not np.array_equal(back("half"), levels[:, live])     # why the rule rejects half for OpenTouch


def test_codec_settings_carry_the_pixel_type_through_encode_sample():
    m = levelled(OT, frames=1)[0][0]
    sample = {"meta": {"k": 1}, "tactile": {"right": m}}
    for pixel, exact in (("float", True), ("half", False)):
        members = encode_sample(sample, CodecSettings(tactile_pixel_type=pixel), "k")
        back = decode_sample(members, "k")["tactile"]["right"]
        assert np.array_equal(back, m) is exact
    with pytest.raises(ValueError, match="pixel type"):
        encode_tactile(m, pixel_type="double")


def test_pipeline_codec_setting_resolves_and_survives_the_worker_round_trip():
    cfg = load_pipeline("opentouch")
    assert cfg.codec.tactile == "auto" and cfg.to_dict()["codec"] == {"tactile": "auto"}
    with pytest.raises(ValueError, match="not resolved"):
        cfg.codec_settings()
    choice = resolve_codec(cfg.codec.tactile, cfg.tactile.compression,
                           [glove_step(load_layout(OT), cfg.normalise_for(load_layout(OT)))])
    resolved = cfg.with_codec_choice(choice)
    again = PipelineConfig.from_dict(resolved.to_dict(), where="worker")
    assert again.codec_settings() == CodecSettings("zip", 95, "float")
    assert CodecChoice.from_info(again.codec.choice) == choice
    block = codec_block({"tactile": {"format": "exr", "pixel_type": "half", "compression": "zip"}, "rgb": {}},
                        choice)
    assert block["tactile"]["pixel_type"] == "float" and block["choice"]["codec"] == "exr_float_zip"
    with pytest.raises(ValueError, match="tactile"):
        PipelineConfig.from_dict({**cfg.to_dict(), "codec": {"tactile": "exr_double"}}, where="p")


def test_the_codec_section_resolves_and_carries_its_choice_without_a_pipeline():
    section = CodecConfig.from_dict({"tactile": "auto"})
    with pytest.raises(ValueError, match="p.toml: .*not resolved"):
        section.resolved("p.toml")
    choice = section.resolve("zip", [glove_step(load_layout(OT))])     # OpenTouch counts: half loses levels
    assert (choice.pixel_type, choice.chosen_by) == ("float", "rule")
    done = section.with_choice(choice, "zip", "p.toml")
    assert done.resolved("p.toml") == choice and section.choice is None          # a copy; the setting is untouched
    assert CodecConfig.from_dict(done.to_dict()) == done and section.to_dict() == {"tactile": "auto"}
    with pytest.raises(ValueError, match="does not match \\[tactile\\] compression 'piz'"):
        section.with_choice(choice, "piz", "p.toml")
    assert CodecConfig("exr_half").resolve("zip", [glove_step(load_layout(OT))]).chosen_by == "pipeline"
