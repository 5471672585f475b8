from types import SimpleNamespace

import pytest

from htdata.ingest.pipeline import PipelineConfig, load_pipeline
from htdata.resources import PIPELINES_DIR


@pytest.mark.parametrize("name", ["opentouch", "touchanything", "native"])
def test_shipped_pipelines_load_and_round_trip(name):
    cfg = load_pipeline(PIPELINES_DIR / f"{name}.toml")
    assert cfg.name == name and cfg.adapter.name == name
    again = PipelineConfig.from_dict(cfg.to_dict())
    assert again.to_dict() == cfg.to_dict()
    assert load_pipeline(name).to_dict() == cfg.to_dict()  # bare name -> pipelines/NAME.toml


def test_opentouch_facts():
    cfg = load_pipeline("opentouch")
    n = cfg.normalise["opentouch_right_16x16"]
    assert (n.convention, n.max_value) == ("inverted", 3072.0)
    p = cfg.adapter.params
    assert p["channel_order"] == "bgr" and p["annotations"] == "annotations.csv" and p["task_field"] == "action"
    assert cfg.sync.max_skew_ns == 20_000_000


def test_touchanything_facts():
    cfg = load_pipeline("touchanything")
    assert cfg.adapter.params["video"] == "chest"
    assert all(n.convention == "direct" and n.max_value == 1.0 for n in cfg.normalise.values())
    assert cfg.layouts == {"left": "touchanything_left_21x21", "right": "touchanything_right_21x21"}


def write(tmp_path, text, name="p.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


MINIMAL = 'name = "x"\n[adapter]\nname = "native"\n'


def test_minimal_gets_defaults(tmp_path):
    cfg = load_pipeline(write(tmp_path, MINIMAL))
    assert cfg.shards.samples_per_shard == 256 and cfg.rgb.size == 224 and cfg.tactile.compression == "zip"


@pytest.mark.parametrize("extra,match", [
    ("bogus = 1\n", "bogus"),
    ("[sync]\nmax_skew = 3\n", "max_skew"),
    ("[rgb]\nsize = 256\n", "rgb/size"),
    ("[rgb]\nquality = 0\n", "quality"),
    ("[tactile]\ncompression = \"dwab\"\n", "compression"),
    ("[shards]\nsamples_per_shard = 0\n", "samples_per_shard"),
    ("[normalise.lay]\nmax_value = 0\n", "max_value"),
    ("[normalise.lay]\nconvention = \"log\"\n", "convention"),
    ("[layouts]\nmiddle = \"x\"\n", "middle"),
])
def test_unknown_keys_and_bad_values_name_the_file(tmp_path, extra, match):
    p = write(tmp_path, MINIMAL + extra, "bad_pipeline.toml")
    with pytest.raises(ValueError, match="bad_pipeline.toml") as e:
        load_pipeline(p)
    assert match in str(e.value)


def test_invalid_toml_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match="broken.toml: invalid TOML"):
        load_pipeline(write(tmp_path, "name = ", "broken.toml"))
    with pytest.raises(FileNotFoundError):
        load_pipeline(tmp_path / "nope.toml")


def test_normalise_falls_back_to_layout_value(tmp_path):
    cfg = load_pipeline(write(tmp_path, MINIMAL + "[normalise.a]\nconvention = \"inverted\"\nmax_value = 4095\n"))
    a = SimpleNamespace(layout_id="a", value={"convention": "direct", "max": 1.0})
    b = SimpleNamespace(layout_id="b", value={"convention": "inverted", "max": 3072})
    assert cfg.normalise_for(a).max_value == 4095.0
    assert cfg.normalise_for(b).convention == "inverted" and cfg.normalise_for(b).max_value == 3072.0


def test_layouts_accept_ids_and_json_paths(tmp_path):
    cfg = load_pipeline(write(tmp_path, MINIMAL + "[layouts]\nleft = \"gloves/my_left.json\"\nright = \"my_right\"\n"))
    assert cfg.layouts == {"left": "gloves/my_left.json", "right": "my_right"}
    with pytest.raises(ValueError, match="layouts/left"):
        load_pipeline(write(tmp_path, MINIMAL + "[layouts]\nleft = \"not an id\"\n", "bad.toml"))


# --------------------------------------------------------------------------- issue #11: hostile settings

@pytest.mark.parametrize("extra,key", [
    ("[sync]\nmax_skew_ms = nan\n", "sync.max_skew_ms"),
    ("[sync]\nmax_skew_ms = inf\n", "sync.max_skew_ms"),
    ("[normalise.glove]\nmax_value = inf\n", "normalise.glove.max_value"),
    ("[normalise.glove]\nscale = -nan\n", "normalise.glove.scale"),
    ("[normalise]\nout_of_range_warn_share = nan\n", "normalise.out_of_range_warn_share"),
])
def test_nan_and_inf_are_refused_naming_the_key(tmp_path, extra, key):
    p = write(tmp_path, MINIMAL + extra)
    with pytest.raises(ValueError, match=rf"{p}: {key} must be a finite number"):
        load_pipeline(p)


def test_nan_anywhere_in_a_dict_is_refused_naming_the_key():
    base = PipelineConfig.from_dict({"name": "x", "adapter": {"name": "native"}}).to_dict()
    with pytest.raises(ValueError, match=r"pipeline: sync.max_skew_ms must be a finite number"):
        PipelineConfig.from_dict({**base, "sync": {"max_skew_ms": float("nan")}})
    nested = {"name": "x", "adapter": {"name": "opentouch", "params": {"hands": ["right", float("inf")]}}}
    with pytest.raises(ValueError, match=r"adapter.params.hands\[1\] must be a finite number"):
        PipelineConfig.from_dict(nested)


@pytest.mark.parametrize("adapter,params,match", [
    ("opentouch", 'anotations = "a.csv"', r"adapter.params.anotations is not a param of adapter 'opentouch'; "
                                          r"known params: channel_order \(str, default 'bgr'\), annotations"),
    ("native", "video = \"chest\"", r"adapter.params.video is not a param of adapter 'native'; known params: none"),
    ("touchanything", "video = 3", r"adapter.params.video must be str .*got int 3"),
    ("opentouch", "allow_unlabelled = 1", r"adapter.params.allow_unlabelled must be bool .*got int 1"),
    ("opentouch", "hands = \"right\"", r"adapter.params.hands must be list"),
])
def test_adapter_params_checked_against_declared(tmp_path, adapter, params, match):
    p = write(tmp_path, f'name = "x"\n[adapter]\nname = "{adapter}"\n[adapter.params]\n{params}\n')
    with pytest.raises(ValueError, match=match):
        load_pipeline(p)


def test_every_adapter_declares_its_params():
    from htdata.source.adapters import ADAPTERS

    for name, cls in ADAPTERS.items():
        assert isinstance(cls.PARAMS, tuple), name
        assert len({p.name for p in cls.PARAMS}) == len(cls.PARAMS)


def test_out_of_range_policy_parsed_and_kept_out_of_to_dict_when_default(tmp_path):
    cfg = load_pipeline(write(tmp_path, MINIMAL))
    assert (cfg.out_of_range.policy, cfg.out_of_range.warn_share) == ("clip", 0.01)
    assert cfg.to_dict()["normalise"] == {}         # defaults add nothing: input fingerprints unchanged
    p = write(tmp_path, MINIMAL + '[normalise]\nout_of_range = "drop_frame"\nout_of_range_warn_share = 0.2\n'
                                  '[normalise.g]\nconvention = "direct"\n', "q.toml")
    cfg = load_pipeline(p)
    assert cfg.out_of_range.policy == "drop_frame" and list(cfg.normalise) == ["g"]
    assert PipelineConfig.from_dict(cfg.to_dict()).to_dict() == cfg.to_dict()
    assert cfg.to_dict()["normalise"]["out_of_range"] == "drop_frame"
    with pytest.raises(ValueError, match="out_of_range"):
        load_pipeline(write(tmp_path, MINIMAL + '[normalise]\nout_of_range = "ignore"\n', "r.toml"))


def test_with_overrides_parses_values_and_validates():
    cfg = load_pipeline("opentouch")
    new = cfg.with_overrides(["adapter.params.annotations=labels v2.tsv", "adapter.params.hands=[\"right\"]",
                              "sync.max_skew_ms=12", "normalise.out_of_range=fail"])
    assert new.adapter.params["annotations"] == "labels v2.tsv" and new.adapter.params["hands"] == ["right"]
    assert new.sync.max_skew_ms == 12.0 and new.out_of_range.policy == "fail" and new.path == cfg.path
    assert cfg.adapter.params["annotations"] == "annotations.csv"      # the original is untouched
    for bad, match in [("sync.max_skew_ms", "expected dotted.key=value"), ("sync..x=1", "expected dotted"),
                       ("sync.max_skew_ms=-1", "max_skew_ms"), ("name.x=1", "is a value, not a table"),
                       ("rgb.bogus=1", "bogus")]:
        with pytest.raises(ValueError, match=match):
            cfg.with_overrides([bad])


def test_set_values_parse_as_toml_but_dates_stay_text():
    from htdata.settings import parse_setting

    assert parse_setting("sync.max_skew_ms=20") == ("sync.max_skew_ms", 20)
    assert parse_setting("tactile.keep_raw=false") == ("tactile.keep_raw", False)
    assert parse_setting("adapter.params.annotations=labels.csv") == ("adapter.params.annotations", "labels.csv")
    # TOML would read these as a date / a time: no setting takes one, the text is meant
    assert parse_setting("adapter.params.session=2026-01-01") == ("adapter.params.session", "2026-01-01")
    assert parse_setting("adapter.params.at=07:32:00") == ("adapter.params.at", "07:32:00")


def test_a_partial_normalise_table_keeps_the_layout_units():
    from htdata.glove.layouts import load_layout
    from htdata.ingest.pipeline import load_pipeline

    cfg = load_pipeline("native").with_overrides(["normalise.opentouch_right_16x16.noise_floor=0.01"])
    n = cfg.normalise_for(load_layout("opentouch_right_16x16"))
    assert (n.convention, n.max_value, n.noise_floor) == ("inverted", 3072.0, 0.01)
    assert cfg.to_dict()["normalise"]["opentouch_right_16x16"] == {"noise_floor": 0.01}


@pytest.mark.parametrize("name", ["opentouch", "touchanything", "native"])
def test_the_pipeline_holds_its_sections_and_writes_what_they_write(name):
    """[sync], [rgb], [tactile], [codec] parse and write themselves (beside the code that reads them);
    the pipeline's dict is theirs, so manifests and unit fingerprints stay what they were."""
    from htdata.format.tactilesettings import TactileConfig
    from htdata.glove.codecsettings import CodecConfig
    from htdata.source.rgbsettings import RgbConfig
    from htdata.source.syncsettings import SyncConfig

    cfg = load_pipeline(name)
    d = cfg.to_dict()
    for key, section in (("sync", SyncConfig), ("rgb", RgbConfig), ("codec", CodecConfig)):
        assert isinstance(getattr(cfg, key), section) and d[key] == getattr(cfg, key).to_dict()
        assert section.from_dict(d[key]) == getattr(cfg, key)
    assert isinstance(cfg.tactile, TactileConfig) and d["tactile"] == cfg.tactile.to_dict()
    assert TactileConfig.from_dict(d["tactile"], "p") == cfg.tactile
    assert set(d["sync"]) == {"max_skew_ms", "policy"} and d["codec"] == {"tactile": "auto"}   # defaults left out
    assert d["rgb"] == {"size": 224, "quality": 95, "crop": "center", "interpolation": "area", "keep_unpaired": True}


def test_toml_integers_in_the_sync_section_become_floats(tmp_path):
    cfg = load_pipeline(write(tmp_path, MINIMAL + "[sync]\nmax_skew_ms = 12\nlag = 40\nmax_lag_ms = 300\n"))
    assert cfg.to_dict()["sync"] == {"max_skew_ms": 12.0, "policy": "nearest", "lag": 40.0, "max_lag_ms": 300.0}
    assert all(isinstance(v, float) for k, v in cfg.to_dict()["sync"].items() if k != "policy")


def test_normalise_is_resolved_once_per_layout_while_the_pipeline_stays_as_it_is(monkeypatch):
    """One NormaliseSettings per pipeline state, and each layout's config resolved once in it (issue 48: it was
    rebuilt on every `normalise_for`, once per episode); a changed table makes a new one."""
    from htdata.glove.layouts import load_layout
    from htdata.glove.normalisesettings import NormaliseSettings

    lid = "opentouch_right_16x16"
    cfg, layout = load_pipeline("opentouch"), load_layout(lid)
    resolved, real = [], NormaliseSettings._resolve
    monkeypatch.setattr(NormaliseSettings, "_resolve",
                        lambda self, lay: resolved.append(lay.layout_id) or real(self, lay))
    first = cfg.normalise_for(layout)
    assert cfg.normalise_settings() is cfg.normalise_settings()
    assert cfg.normalise_for(load_layout(lid)) is first and resolved == [lid]     # another load of the same layout
    changed = cfg.with_overrides([f"normalise.{lid}.noise_floor=0.1"])
    assert changed.normalise_for(layout).noise_floor == 0.1 and first.noise_floor == 0 and resolved == [lid, lid]
    cfg.normalise[lid].max_value = 4000.0     # a table changed in place: a new settings object, resolved again
    assert cfg.normalise_for(layout).max_value == 4000 and first.max_value == 3072 and len(resolved) == 3
