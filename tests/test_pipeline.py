from types import SimpleNamespace

import pytest

from htdata.pipeline import PipelineConfig, load_pipeline
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
