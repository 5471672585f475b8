"""The deprecated old names (htdata/_moved.py): one mechanism, every name warns, and an end date."""

import importlib
import sys
import warnings

import pytest

import htdata
from htdata import _moved


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(part) for part in text.split(".")[:2])


def test_the_shim_is_removed_by_the_version_it_promised():
    # Fails on the release that reaches REMOVED_IN: delete htdata/_moved.py, the `__getattr__`
    # hand-offs of the modules in its MOVED_NAMES and this test, as the deprecation warnings announced.
    assert _version(htdata.__version__) < _moved.REMOVED_IN, (
        f"htdata {htdata.__version__} reached {_moved.REMOVED_IN}: remove the deprecated names")


@pytest.mark.parametrize("package, name, target", [
    ("htdata.format", "SHARDS_DIR", "htdata.format.table"),
    ("htdata.curate", "plan_edit", "htdata.curate.edit"),
    ("htdata.source.adapters.base", "walk_source", "htdata.source.adapters.sourcetree"),
    ("htdata.source.adapters.base", "sanitise_id", "htdata.source.adapters.discovery"),
])
def test_an_old_name_of_a_package_warns_and_is_the_same_object(package, name, target):
    module = importlib.import_module(package)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(target), name)
    assert [w.category for w in caught] == [DeprecationWarning]
    assert f"{target}.{name}" in str(caught[0].message)


def test_an_old_module_name_warns():
    sys.modules.pop("htdata.keys", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = importlib.import_module("htdata.keys")
    assert old is importlib.import_module("htdata.read.keys")
    assert any(w.category is DeprecationWarning and "htdata.read.keys" in str(w.message) for w in caught)


def test_a_name_renamed_as_it_moved_warns_with_its_new_name():
    base = importlib.import_module("htdata.source.adapters.base")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = base.check_adapter_params
    assert value is importlib.import_module("htdata.source.adapters.params").check_declared_params
    assert "htdata.source.adapters.params.check_declared_params" in str(caught[0].message)


@pytest.mark.parametrize("old, new", [("htdata.pipeline", "htdata.ingest.pipeline"),
                                      ("htdata.curate.repack", "htdata.write.repack"),
                                      ("htdata.sample.corpus", "htdata.synthetic.corpus"),
                                      ("htdata.repack", "htdata.write.repack"),
                                      ("htdata.curate.splitrule", "htdata.store.splitrule")])
def test_the_house_pass_moves_warn_and_name_the_new_module(old, new):
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
    assert module is importlib.import_module(new)
    assert any(w.category is DeprecationWarning and new in str(w.message) for w in caught)


@pytest.mark.parametrize("module, name, target, new", [
    ("htdata.format.table", "CANVAS", "htdata.format.canvas", "CANVAS"),
    ("htdata.glove.layouts", "parse_canonical", "htdata.glove.canonical", "parse_canonical"),
    ("htdata.source.lag", "LAG_MODES", "htdata.source.syncsettings", "LAG_MODES"),
    ("htdata.ingest.pipeline", "parse_setting", "htdata.settings", "parse_setting"),
    ("htdata.curate.edit", "NoSuchEpisode", "htdata.store.episodeids", "NoSuchEpisode"),
    ("htdata.curate.split", "episode_uniform", "htdata.store.splitrule", "episode_uniform"),
    ("htdata.curate.split", "list_splits", "htdata.store.splitfiles", "list_splits"),
    ("htdata.read.reader", "SplitRejected", "htdata.store.splitfiles", "SplitRejected"),
    ("htdata.read.torchdata", "FRAME_KINDS", "htdata.read.itemoptions", "FRAME_KINDS"),
    ("htdata.read.torchdata", "_ItemBuilder", "htdata.read.torchitems", "ItemBuilder"),
    ("htdata.format.codec", "check_served_maps", "htdata.format.tactilecodec", "check_served_maps"),
    ("htdata.glove.normalise", "RAW_COUNT_DEFAULTS", "htdata.glove.normaliseconfig", "RAW_COUNT_DEFAULTS"),
])
def test_a_module_hands_on_the_names_it_no_longer_re_exports(module, name, target, new):
    if module == "htdata.read.torchdata":
        pytest.importorskip("torch")
    with pytest.warns(DeprecationWarning, match=f"{module}.{name} is deprecated: it moved to {target}.{new}"):
        value = getattr(importlib.import_module(module), name)
    assert value is getattr(importlib.import_module(target), new)


@pytest.mark.parametrize("package", ["htdata.format", "htdata.curate", "htdata.source.adapters.base"])
def test_a_name_that_never_existed_is_an_attribute_error(package):
    module = importlib.import_module(package)
    with pytest.raises(AttributeError, match="no_such_name"):
        module.no_such_name  # noqa: B018
    assert not hasattr(module, "__wrapped__")   # dunder probes (inspect, pickle) stay AttributeErrors


def test_a_renamed_keyword_warns_translates_old_values_and_refuses_both_names():
    @_moved.renamed_keyword("colour", "color", {"gray": "grey"})
    def paint(thing, color="red"):
        """Paint a thing."""
        return thing, color

    assert paint("door") == ("door", "red") and paint("door", color="blue") == ("door", "blue")
    with pytest.warns(DeprecationWarning, match=r"paint\(colour='gray'\) is deprecated: write color='grey'"):
        assert paint("door", colour="gray") == ("door", "grey")
    with pytest.warns(DeprecationWarning, match="goes in htdata"):
        assert paint("door", colour="blue") == ("door", "blue")
    with pytest.raises(TypeError, match="both colour= and color="):
        paint("door", colour="blue", color="red")
    assert paint.__doc__ == "Paint a thing." and paint.__name__ == "paint"
