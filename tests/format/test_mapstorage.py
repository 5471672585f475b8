"""MapStorage (htdata/format/mapstorage.py): the one owner of "are maps stored", its words and its rules.

The datasets themselves (both kinds ingested, read, validated, merged, appended) are in tests/read/test_maps_raw.py;
here the value type and the ingest's hand-off to its workers, without a dataset.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from htdata.errors import ConfigError, DatasetError
from htdata.format.mapstorage import MapStorage
from htdata.format.tactilesettings import TactileConfig
from htdata.ingest.pipeline import load_pipeline
from htdata.ingest.plan import Source, plan_units
from htdata.resources import SCHEMAS_DIR

RAW_PARENT = {"codec": {"tactile": {"raster_mode": "nearest", "maps": "raw"}}}
STORED_PARENT = {"codec": {"tactile": {"raster_mode": "nearest", "maps": "stored"}}}
UNRECORDED_PARENT = {"codec": {"tactile": {"raster_mode": "nearest"}}}   # written before the setting


@pytest.mark.parametrize("value, hint", [("rwa", "did you mean 'raw'"), ("Stored", "did you mean 'stored'"),
                                         ("sometimes", ""), (1, "")])
def test_a_setting_that_is_not_a_word_is_one_config_error_naming_the_setting(value, hint):
    with pytest.raises(ConfigError) as exc:
        MapStorage.parse(value, "my.toml")
    message = str(exc.value)
    assert message.startswith(f"my.toml: [tactile] maps = {value!r}: must be one of 'auto', 'stored', 'raw'")
    assert hint in message and "\n" not in message
    with pytest.raises(ConfigError, match=r"\[tactile\] maps"):
        TactileConfig.from_dict({"maps": value}, "my.toml")


def test_the_words_parse_and_the_schema_allows_exactly_them():
    assert [MapStorage.parse(w) for w in ("auto", "stored", "raw")] == list(MapStorage)
    schema = json.loads((Path(SCHEMAS_DIR) / "pipeline.schema.json").read_text())
    assert schema["properties"]["tactile"]["properties"]["maps"]["enum"] == [m.value for m in MapStorage]
    assert TactileConfig().maps is MapStorage.AUTO and TactileConfig.from_dict({}, "p").maps is MapStorage.AUTO


@pytest.mark.parametrize("setting, parent, chosen", [
    (MapStorage.AUTO, None, MapStorage.STORED),               # a new dataset stores its maps
    (MapStorage.AUTO, RAW_PARENT, MapStorage.RAW),            # an append keeps its parent's choice
    (MapStorage.AUTO, STORED_PARENT, MapStorage.STORED),
    (MapStorage.AUTO, UNRECORDED_PARENT, MapStorage.STORED),  # a parent without the record stores maps
    (MapStorage.STORED, RAW_PARENT, MapStorage.STORED),       # explicit: taken as given (the commit refuses it)
    (MapStorage.RAW, None, MapStorage.RAW),
])
def test_auto_resolves_to_the_parents_choice_on_append_else_stored(setting, parent, chosen):
    assert setting.resolved(parent) is chosen


def test_the_record_reads_absent_as_stored_and_refuses_other_words():
    assert MapStorage.of(UNRECORDED_PARENT) is MapStorage.STORED and MapStorage.of({}) is MapStorage.STORED
    assert MapStorage.of(RAW_PARENT) is MapStorage.RAW and not MapStorage.RAW.stores_maps
    for word in ("auto", "best", "Raw"):
        with pytest.raises(DatasetError, match=f"codec.tactile.maps = '{word}'"):
            MapStorage.of({"codec": {"tactile": {"maps": word}}})
    filled = MapStorage.comparable_codec(UNRECORDED_PARENT["codec"])
    assert filled == STORED_PARENT["codec"] and "maps" not in UNRECORDED_PARENT["codec"]["tactile"]
    assert MapStorage.RAW.map_member("left") == "raw_left.npy"
    assert MapStorage.STORED.map_member("right") == "tactile_right.exr"


def test_an_unresolved_auto_says_nothing_about_maps():
    """No question about stored maps is answered for AUTO: an ingest resolves it first."""
    for ask in (lambda: MapStorage.AUTO.stores_maps, lambda: MapStorage.AUTO.record,
                lambda: MapStorage.AUTO.map_member("left")):
        with pytest.raises(RuntimeError, match="not resolved"):
            ask()


def test_the_pipeline_dict_keeps_its_bytes_only_raw_is_written():
    """[tactile] maps in to_dict (manifest sources, episode settings, unit fingerprints): as before the type."""
    assert [m.pipeline_value for m in MapStorage] == [None, None, "raw"]
    base = load_pipeline("opentouch")
    for word in ("auto", "stored"):
        assert "maps" not in base.with_overrides([f"tactile.maps={word}"]).to_dict()["tactile"]
    assert base.with_overrides(["tactile.maps=raw"]).to_dict()["tactile"]["maps"] == "raw"


def test_an_explicit_stored_survives_a_later_override():
    once = load_pipeline("opentouch").with_overrides(["tactile.maps=stored"])
    assert once.with_overrides(["rgb.quality=90"]).tactile.maps is MapStorage.STORED


@pytest.mark.parametrize("setting, keep_raw, raster_mode, message", [
    ("tactile.keep_raw=false", False, "nearest", "needs keep_raw = true"),
    ("tactile.raster_mode=bilinear", True, "bilinear", 'needs raster_mode = "nearest"'),
])
def test_raw_without_its_raw_rows_or_a_nearest_raster_is_refused_by_the_type(setting, keep_raw, raster_mode, message):
    with pytest.raises(ConfigError, match=r"\[tactile\] maps = \"raw\"") as exc:
        load_pipeline("opentouch").with_overrides(["tactile.maps=raw", setting])
    assert message in str(exc.value)
    # the one place that says it: the error comes out of MapStorage.check_tactile
    assert (Path(exc.traceback[-1].path).name, exc.traceback[-1].name) == ("mapstorage.py", "check_tactile")
    with pytest.raises(ConfigError, match=message):
        MapStorage.RAW.check_tactile(keep_raw, raster_mode, "p")
    MapStorage.STORED.check_tactile(keep_raw, raster_mode, "p")   # nothing to refuse
    MapStorage.AUTO.check_tactile(keep_raw, raster_mode, "p")     # resolved to RAW on append: with_maps checks


def test_a_worker_is_told_the_resolved_choice_not_left_to_a_missing_key(tmp_path):
    """The pipeline dict leaves "stored" out; the unit task carries the choice itself, and an unresolved
    setting is never handed to a worker."""
    pipeline = load_pipeline("native")
    ref = SimpleNamespace(source_files=())           # a planned episode reading no file (plan_units assigns hashing)
    with pytest.raises(RuntimeError, match="not resolved"):
        plan_units([(ref, Source(pipeline, tmp_path))], tmp_path, 0)
    for chosen in (MapStorage.STORED, MapStorage.RAW):
        [task] = plan_units([(ref, Source(pipeline.with_maps(chosen), tmp_path))], tmp_path, 0)
        assert task.maps is chosen
        assert ("maps" in task.pipeline["tactile"]) == (chosen is MapStorage.RAW)
