"""[tactile] maps = "raw": no map members stored, every htdata reader renders them from the raw rows.

One tiny sample corpus (all three source formats) ingested twice, maps stored and maps not stored; the
second must serve exactly the first's maps everywhere a map is read.
"""

from __future__ import annotations

import json
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pytest

from htdata.cli import main as cli
from htdata.errors import DatasetError
from htdata.format.mapstorage import MapStorage
from htdata.format.table import HANDS, SHARDS_DIR, tactile_member
from htdata.ingest.pipeline import load_pipeline
from htdata.read.itemoptions import ItemOptions
from htdata.read.reader import DatasetReader
from htdata.synthetic.corpus import CorpusConfig, write_corpus
from htdata.validate.validator import validate_dataset
from tests.factories import ingest_cli, rewrite_manifest

PIPELINES = ("opentouch", "touchanything", "native")


def _ingest(corpus: Path, out: Path, maps: str) -> None:
    args = [a for name in PIPELINES for a in ("--pipeline", f"{name}={corpus / name}")]
    assert ingest_cli(*args, "--set", f"tactile.maps={maps}", out) == 0


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    """(maps stored, maps not stored): the same tiny corpus ingested both ways."""
    tmp = tmp_path_factory.mktemp("maps")
    write_corpus(CorpusConfig(out=tmp / "raw", seed=0, scale="tiny", progress=False))
    _ingest(tmp / "raw", tmp / "stored", "stored")
    _ingest(tmp / "raw", tmp / "rendered", "raw")
    return tmp / "stored", tmp / "rendered"


def test_manifest_records_the_choice_and_shards_hold_no_maps(pair):
    stored, rendered = pair
    a, b = DatasetReader(stored), DatasetReader(rendered)
    assert MapStorage.of(a.manifest) is MapStorage.STORED and MapStorage.of(b.manifest) is MapStorage.RAW
    assert (a.manifest["codec"]["tactile"]["maps"], b.manifest["codec"]["tactile"]["maps"]) == ("stored", "raw")
    assert b.manifest["codec"]["tactile"]["raster_mode"] == "nearest"
    assert b.manifest["counts"]["frames_per_hand"] == a.manifest["counts"]["frames_per_hand"]
    assert a.manifest["counts"]["frames_per_hand"]["left"] > 0
    names = [n for s in b.manifest["shards"] for n in tarfile.open(rendered / SHARDS_DIR / s["name"]).getnames()]
    assert names and not [n for n in names if n.endswith(".exr")]
    assert any(n.endswith("raw_left.npy") for n in names) and any(n.endswith(".json") for n in names)
    assert all(int(b.index[f"size_tactile_{h}"].max()) == 0 for h in HANDS)
    assert sum(s["bytes"] for s in b.manifest["shards"]) < 0.9 * sum(s["bytes"] for s in a.manifest["shards"])


def test_decoded_maps_equal_the_stored_ones_exactly(pair):
    a, b = (DatasetReader(p) for p in pair)
    assert len(a) == len(b) > 300
    maps = 0
    for i in range(len(a)):
        sa, sb = a.decoded(i), b.decoded(i)
        assert a.key(i) == b.key(i) and sorted(sa["tactile"]) == sorted(sb["tactile"])
        for hand in sa["tactile"]:
            assert sb["tactile"][hand].dtype == np.float32
            np.testing.assert_array_equal(sb["tactile"][hand], sa["tactile"][hand])
            maps += 1
        np.testing.assert_array_equal(sb["rgb"], sa["rgb"])
    assert maps > len(a)       # both hands of the two-handed episodes too
    # a map asked for alone comes alone, rendered from the raw rows read for it
    one = b.decoded(0, (tactile_member("right"),))
    assert list(one["tactile"]) == ["right"] and not one["raw"] and "meta" not in one
    np.testing.assert_array_equal(one["tactile"]["right"], a.decoded(0)["tactile"]["right"])
    streamed = dict(b.iter_samples(decode=True))
    for i in (0, len(a) // 2, len(a) - 1):
        for hand, m in a.decoded(i)["tactile"].items():
            np.testing.assert_array_equal(streamed[i]["tactile"][hand], m)
    wa, wb = a.window(1, 3, 2), b.window(1, 3, 2)
    for fa, fb in zip(wa, wb):
        for hand in fa["tactile"]:
            np.testing.assert_array_equal(fb["tactile"][hand], fa["tactile"][hand])


def test_torch_datasets_serve_the_same_maps(pair):
    pytest.importorskip("torch")
    from htdata.read.torchdata import TactileFrameDataset, TactileStream, TactileWindowDataset

    stored, rendered = pair
    fa, fb = TactileFrameDataset(stored), TactileFrameDataset(rendered)
    assert len(fa) == len(fb) > 0 and np.array_equal(fa.items, fb.items)
    for i in (0, len(fa) // 3, len(fa) - 1):
        assert np.array_equal(fa[i]["tactile"].numpy(), fb[i]["tactile"].numpy())
    wa, wb = TactileWindowDataset(stored, window=3), TactileWindowDataset(rendered, window=3)
    assert np.array_equal(wa.items, wb.items)
    assert np.array_equal(wa[5]["tactile"].numpy(), wb[5]["tactile"].numpy())
    tactile = ItemOptions(frames="tactile")
    sa, sb = list(TactileStream(stored, options=tactile)), list(TactileStream(rendered, options=tactile))
    assert len(sa) == len(sb) == len(fa)
    assert all(np.array_equal(x["tactile"].numpy(), y["tactile"].numpy()) for x, y in zip(sa, sb))
    with pytest.raises(ValueError, match="stores no tactile maps"):
        TactileFrameDataset(rendered, options=ItemOptions(maps_from="stored"))


def test_validate_deep_passes_and_checks_the_rendered_maps(pair):
    report = validate_dataset(pair[1], deep=True)
    assert report["ok"], report["checks"]
    content = report["checks"]["content"]["checked"]
    assert content["served_maps_rendered"] == DatasetReader(pair[1]).manifest["counts"]["frames_per_hand"]["left"] \
        + DatasetReader(pair[1]).manifest["counts"]["frames_per_hand"]["right"]
    assert report["stats"]["frames_per_hand"] == validate_dataset(pair[0])["stats"]["frames_per_hand"]


def test_a_map_member_in_a_version_without_maps_fails_validate(pair, tmp_path):
    """The record says "raw": an index listing tactile maps contradicts it (and the reverse is the stored case)."""
    copy = shutil.copytree(pair[0], tmp_path / "ds")
    manifest = DatasetReader(copy).manifest
    manifest["codec"]["tactile"]["maps"] = "raw"
    rewrite_manifest(copy, manifest)
    report = validate_dataset(copy)
    failed = {f["what"]: f["message"] for f in report["checks"]["structure"]["failures"]}
    assert "hand_member" in failed and "maps = \"raw\"" in failed["hand_member"]


def test_a_manifest_claiming_stored_maps_over_shards_without_them_is_refused_by_the_reader(pair, tmp_path):
    """Issue 44 weak edge: it was served as samples with no maps at all (validate already failed it)."""
    from htdata.errors import DatasetError

    copy = shutil.copytree(pair[1], tmp_path / "ds")
    manifest = DatasetReader(copy).manifest
    manifest["codec"]["tactile"]["maps"] = "stored"
    rewrite_manifest(copy, manifest)
    reader = DatasetReader(copy)
    with pytest.raises(DatasetError, match=r"raw_(left|right)\.npy but no tactile_(left|right)\.exr"):
        for i in range(len(reader)):
            reader.decoded(i)
    assert not validate_dataset(copy)["ok"]


def test_inspect_and_export_run_on_rendered_maps(pair, tmp_path, capsys):
    stored, rendered = pair
    assert cli(["preview", str(rendered), str(tmp_path / "p.png")]) == 0
    assert cli(["preview", str(stored), str(tmp_path / "q.png")]) == 0
    assert (tmp_path / "p.png").read_bytes() == (tmp_path / "q.png").read_bytes()
    capsys.readouterr()
    assert cli(["stats", str(rendered), "--json", "--no-cache", "--health", str(tmp_path / "h.png")]) == 0
    got = json.loads(capsys.readouterr().out)
    assert cli(["stats", str(stored), "--json", "--no-cache"]) == 0
    want = json.loads(capsys.readouterr().out)
    got.pop("dataset", None), want.pop("dataset", None)
    assert json.dumps(got, sort_keys=True).replace(str(rendered), "") == \
        json.dumps(want, sort_keys=True).replace(str(stored), "")
    assert (tmp_path / "h.png").stat().st_size > 0
    assert cli(["card", str(rendered), str(tmp_path / "card.html")]) == 0
    assert "not stored" in (tmp_path / "card.md").read_text()
    pytest.importorskip("pyarrow")
    assert cli(["export", "lerobot", str(rendered), str(tmp_path / "lr"), "--maps"]) == 0
    assert list((tmp_path / "lr" / "videos").glob("observation.tactile.right.map/*/*.mp4"))


def test_renormalise_of_unstored_maps_serves_the_new_calibration(pair, tmp_path):
    stored, rendered = (shutil.copytree(p, tmp_path / p.name) for p in pair)
    for root in (stored, rendered):
        assert cli(["renormalise", str(root), "--pipeline", "opentouch",
                    "--set", "normalise.opentouch_right_16x16.max_value=2500"]) == 0
    a, b, before = DatasetReader(stored), DatasetReader(rendered), DatasetReader(rendered, version=1)
    changed = 0
    for i in range(len(a)):
        sa, sb, s0 = a.decoded(i)["tactile"], b.decoded(i)["tactile"], before.decoded(i)["tactile"]
        for hand in sa:
            np.testing.assert_array_equal(sb[hand], sa[hand])
            changed += not np.array_equal(sb[hand], s0[hand])
    assert changed > 0
    assert not [n for s in b.manifest["shards"] for n in tarfile.open(rendered / SHARDS_DIR / s["name"]).getnames()
                if n.endswith(".exr")]


def test_merge_of_different_choices_is_refused(pair, tmp_path, capsys):
    assert cli(["merge", str(pair[0]), str(pair[1]), str(tmp_path / "m")]) != 0
    err = capsys.readouterr().err
    assert "tactile.maps" in err and "stored vs raw" in err
    assert not (tmp_path / "m" / "dataset.json").exists()


def test_append_with_the_other_choice_is_refused(pair, tmp_path, capsys):
    copy = shutil.copytree(pair[1], tmp_path / "ds")
    corpus = Path(pair[0]).parent / "raw"
    assert ingest_cli("--pipeline", f"native={corpus / 'native'}", "--set", "tactile.maps=stored", copy) != 0
    assert "tactile.maps" in capsys.readouterr().err


@pytest.mark.parametrize("setting, message", [
    ("tactile.keep_raw=false", "keep_raw = true"),
    ("tactile.raster_mode=bilinear", 'raster_mode = "nearest"'),
])
def test_raw_maps_need_raw_rows_and_a_nearest_raster(setting, message):
    with pytest.raises(ValueError, match="maps") as exc:
        load_pipeline("opentouch").with_overrides(["tactile.maps=raw", setting])
    assert message in str(exc.value)


def test_a_typo_in_the_value_is_an_error_naming_the_allowed_values(capsys, tmp_path):
    with pytest.raises(ValueError, match="maps") as exc:
        load_pipeline("opentouch").with_overrides(["tactile.maps=rwa"])
    assert "'stored'" in str(exc.value) and "'raw'" in str(exc.value)
    assert ingest_cli("--pipeline", "opentouch", "--set", "tactile.maps=Raw", tmp_path, tmp_path / "out") != 0
    assert "tactile" in capsys.readouterr().err


def test_a_version_without_the_record_stores_its_maps():
    assert MapStorage.of({"codec": {"tactile": {"raster_mode": "nearest"}}}).stores_maps
    assert not MapStorage.of({"codec": {"tactile": {"maps": "raw"}}}).stores_maps
    with pytest.raises(DatasetError, match="not one of"):
        MapStorage.of({"codec": {"tactile": {"maps": "sometimes"}}})


def test_auto_keeps_the_parents_choice_on_append_and_stores_maps_in_a_new_dataset(pair, tmp_path):
    """The default "auto": an append to a dataset that stores its maps stores them too (nothing refused),
    one that does not stays without; a new dataset stores its maps, raw rows kept or not."""
    stored, rendered = pair
    corpus = Path(stored).parent / "raw"
    for parent, kind in ((stored, "stored"), (rendered, "raw")):
        copy = shutil.copytree(parent, tmp_path / kind)
        assert cli(["rm", str(copy), "ot-*"]) == 0                      # the append re-ingests these
        old_shards = {s["name"] for s in DatasetReader(copy).manifest["shards"]}
        assert ingest_cli("--pipeline", f"opentouch={corpus / 'opentouch'}", copy) == 0
        after = DatasetReader(copy)
        new_shards = [s["name"] for s in after.manifest["shards"] if s["name"] not in old_shards]
        names = [n for s in new_shards for n in tarfile.open(copy / SHARDS_DIR / s).getnames()]
        assert new_shards and MapStorage.of(after.manifest).record == kind
        assert any(n.endswith(".exr") for n in names) == (kind == "stored")
    new = tmp_path / "new"
    assert ingest_cli("--pipeline", f"native={corpus / 'native'}", new) == 0
    assert MapStorage.of(DatasetReader(new).manifest) is MapStorage.STORED
    no_raw = tmp_path / "no_raw"
    assert ingest_cli("--pipeline", f"native={corpus / 'native'}", "--set", "tactile.keep_raw=false", no_raw) == 0
    assert MapStorage.of(DatasetReader(no_raw).manifest) is MapStorage.STORED


def test_an_explicit_raw_onto_stored_maps_is_refused(pair, tmp_path, capsys):
    copy = shutil.copytree(pair[0], tmp_path / "ds")
    corpus = Path(pair[0]).parent / "raw"
    assert ingest_cli("--pipeline", f"native={corpus / 'native'}", "--set", "tactile.maps=raw", copy) != 0
    assert "tactile.maps" in capsys.readouterr().err


def test_auto_can_be_written_out_and_is_the_default():
    assert load_pipeline("opentouch").tactile.maps is MapStorage.AUTO
    assert load_pipeline("opentouch").with_overrides(["tactile.maps=auto"]).tactile.maps is MapStorage.AUTO
