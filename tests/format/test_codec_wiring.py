"""[codec] tactile = "auto" through a real ingest: the rule's choice reaches the members, the manifest and validate."""

import json

from htdata.format.tactilecodec import decode_exr_pixels
from htdata.read.reader import DatasetReader
from htdata.validate import validate_dataset
from tests.factories import PIPELINES_DIR, ingest_cli, make_native, make_touchanything


def _pixels(root) -> set:
    with DatasetReader(root) as r:
        return {str(decode_exr_pixels(data).dtype) for i in range(len(r))
                for s, data in r.sample(i).items() if s.startswith("tactile_")}


def test_auto_picks_float_for_opentouch_gloves_and_half_for_touchanything(tmp_path):
    ot = tmp_path / "ot"
    assert ingest_cli("--pipeline", "native", "--set", "tactile.maps=stored", make_native(tmp_path / "src_native"),
                      ot) == 0
    m = json.loads((ot / "dataset.json").read_text())
    assert m["codec"]["tactile"]["pixel_type"] == "float" and _pixels(ot) == {"float32"}
    assert m["codec"]["choice"]["chosen_by"] == "rule" and "opentouch_right_16x16" in m["codec"]["choice"]["reason"]
    assert validate_dataset(ot, deep=True)["ok"]
    ta = tmp_path / "ta"
    assert ingest_cli("--pipeline", "touchanything", "--set", "tactile.maps=stored",
                      make_touchanything(tmp_path / "src_ta"), ta) == 0
    m = json.loads((ta / "dataset.json").read_text())
    assert m["codec"]["choice"]["codec"] == "exr_half_zip" and _pixels(ta) == {"float16"}


def test_explicit_setting_and_append_keep_one_codec(tmp_path):
    src = make_native(tmp_path / "src")
    pipe = tmp_path / "native.toml"
    pipe.write_text((PIPELINES_DIR / "native.toml").read_text().replace("[tactile]", '[tactile]\nmaps = "stored"')
                    + '\n[codec]\ntactile = "exr_half"\n')
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", pipe, src, out) == 0
    m = json.loads((out / "dataset.json").read_text())
    assert m["codec"]["choice"]["chosen_by"] == "pipeline" and "levels NOT kept for: opentouch" in m["codec"]["choice"]["reason"]
    # appending with "auto" to this half dataset keeps half (one codec per dataset) and says so
    assert ingest_cli("--pipeline", "native", "--set", "tactile.maps=stored", src, out) == 0
    m = json.loads((out / "dataset.json").read_text())
    assert m["codec"]["tactile"]["pixel_type"] == "half" and _pixels(out) == {"float16"}
    assert m["codec"]["choice"]["chosen_by"] == "dataset" and "would pick exr_float_zip" in m["codec"]["choice"]["reason"]
    assert m["version"] == 2 and validate_dataset(out, deep=True)["ok"]
