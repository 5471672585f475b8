"""handtouch.compare: the rows' configs and the comparison table, on a tiny synthetic dataset."""

import json

import pytest

from handtouch.bench.items import EvalConfig, prepare
from handtouch.compare import ABLATION, BASELINE, DESIGN, OURS, ROWS, compare, parse_args, resolve_rows
from handtouch.config import load_train_config
from handtouch.rgb_encoder import TactileGridRGB
from handtouch.rgb_pretrain import save_probe
from tests.factories import TRAIN_EPISODES, write_synthetic_dataset
from tests.factories.train import TINY, write_toml


# Every encoder narrow enough for a few CPU steps; the baselines' widths are the config's.
@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory):
    root = write_synthetic_dataset(tmp_path_factory.mktemp("ds") / "ds", TRAIN_EPISODES, seed=3)
    from htdata.curate.split import make_split
    make_split(root, ood_tasks=["grab"], test_ratio=0.5, seed=0, name="s")
    return root


@pytest.fixture
def tiny_config(dataset_root, tmp_path):
    # a (untrained) probe file as the frozen RGB encoder: the RGB-prior row needs its readout
    probe = tmp_path / "probe.pt"
    save_probe(TactileGridRGB(size=16, width=8, channels=4, grid=14, hidden=16), probe, {"pairing": "aligned"})
    path = tmp_path / "tiny.toml"
    write_toml(path, {**TINY, "data_root": str(dataset_root), "rgb_encoder": str(probe)})
    return path


def test_rows_cover_the_papers_comparison():
    groups = {g: [r.label for r in ROWS if r.group == g] for g in (OURS, BASELINE, ABLATION, DESIGN)}
    assert groups[BASELINE] == ["CNN", "ResNet-18", "VQ-VAE", "ViT"]
    assert groups[ABLATION] == ["w/o drop", "w/o codebook", "w/o vision"]
    assert len(groups[OURS]) == 1 and ROWS[0].overrides == ()
    assert len({r.key for r in ROWS}) == len(ROWS)
    assert not any("|" in r.label + r.definition for r in ROWS)     # markdown table cells


def test_each_row_changes_only_its_overrides(tiny_config, tmp_path):
    resolved = resolve_rows(tiny_config, [], list(ROWS), tmp_path)
    base = load_train_config(tiny_config)
    dirs = set()
    for row, cfg, same_as in resolved:
        assert same_as == ""
        dirs.add(cfg.out_dir)
        assert cfg.out_dir.startswith(str(tmp_path / "train" / f"{row.key}-"))
        expected = load_train_config(tiny_config, list(row.overrides))
        expected.out_dir = cfg.out_dir
        assert cfg == expected
        if row.overrides:
            assert cfg != base or row.group == OURS
    assert len(dirs) == len(ROWS)
    by_key = {row.key: cfg for row, cfg, _ in resolved}
    assert by_key["vqvae"].model.encoder == "vqvae" and by_key["vit_plain"].model.encoder == "vit_plain"
    assert not by_key["no_drop"].masking.curriculum and not by_key["no_codebook"].model.codebook
    assert not by_key["no_vision"].model.vision and by_key["two_channel"].model.mask_channel
    assert by_key["rgb_prior"].model.rgb_prior and not by_key["handtouch"].model.rgb_prior
    assert by_key["stage3_replay"].loss.stage3_replay == 1.0 and by_key["stage3_replay"].loss.stage3_vq
    assert by_key["handtouch"].loss.stage3_replay == 0.0 and not by_key["handtouch"].loss.stage3_vq


def test_a_row_equal_to_the_base_config_is_marked_not_retrained(tiny_config, tmp_path):
    sets = ["loss.stage3_replay=1.0", "loss.stage3_vq=true"]      # the design row already on in the base
    resolved = {row.key: (cfg, same) for row, cfg, same in resolve_rows(tiny_config, sets, list(ROWS), tmp_path)}
    assert resolved["stage3_replay"][1] == "handtouch"
    assert resolved["stage3_replay"][0].out_dir.rsplit("-", 1)[1] == resolved["handtouch"][0].out_dir.rsplit("-", 1)[1]
    assert all(same == "" for key, (_, same) in resolved.items() if key != "stage3_replay")


def test_compare_trains_and_tables_every_row(dataset_root, tiny_config, tmp_path):
    prepared = prepare(str(dataset_root), "s", ("test",), EvalConfig(max_items=4, seed=0))
    out = tmp_path / "cmp"
    doc = compare(tiny_config, [], prepared, out, log=lambda *_: None)
    assert [r["key"] for r in doc["rows"]] == [r.key for r in ROWS]
    on_disk = json.loads((out / "compare.json").read_text())
    assert [r["label"] for r in on_disk["rows"]] == [r.label for r in ROWS]
    assert set(on_disk["references"]) == {"zeros-ref", "copy-last-ref"}
    md = (out / "compare.md").read_text()
    table = md.split("## test: covered pixels")[1].split("##")[0]
    for label in [r.label for r in ROWS] + ["zeros-ref", "copy-last-ref"]:
        assert f"| {label} (test) |" in table, label
    for header in ("Retrieval Hit@1", "Inpaint F-RMSE", "H-RMSE", "RGB2T F-RMSE", "Pred F-RMSE"):
        assert header in table
    for r in doc["rows"]:
        tracks = r["results"]["test"]
        assert 0 <= tracks["prediction"]["f_covered"]["rmse"] < 1, r["key"]
        assert r["steps"] == {"1": 1, "2": 1, "3": 1}
        quantised = r["key"] not in ("vit_plain", "no_codebook")
        assert (r["perplexity"] is not None) == quantised, r["key"]
    assert doc["rows"][0]["model"] == "handtouch-vit" and doc["rows"][3]["model"] == "baseline-vqvae"
    # a re-run reuses every finished row (same resolved config -> same folder, stages skipped)
    again = compare(tiny_config, [], prepared, out, rows=[ROWS[0]], log=lambda *_: None)
    assert again["rows"][0]["out_dir"] == doc["rows"][0]["out_dir"]
    assert again["rows"][0]["results"]["test"]["prediction"] == doc["rows"][0]["results"]["test"]["prediction"]


def test_cli_rows_and_parts_are_checked():
    args = parse_args(["--config", "x.toml", "--rows", "handtouch,vqvae", "--parts", "test"])
    assert [r.key for r in args.rows] == ["handtouch", "vqvae"] and args.parts == ["test"]
    with pytest.raises(SystemExit):
        parse_args(["--config", "x.toml", "--rows", "handtouch,nope"])
