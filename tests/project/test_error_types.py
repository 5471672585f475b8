"""A mistake a user can make raises one of htdata.errors' types, so a caller can catch it by kind.

ConfigError: a setting the user wrote; ArgumentError: an argument a caller passed; DatasetError: a
dataset or member not what its records say. Each is also a ValueError (older `except ValueError`).
"""

from __future__ import annotations

import inspect
import json

import pytest

from handtouch.config import load_train_config
from htdata import errors
from htdata.commands.version_arg import parse_version
from htdata.curate.merge import MergeConflict
from htdata.errors import ArgumentError, ConfigError, DatasetError, HtdataError, RecordMismatch
from htdata.format.table import MEMBER_ORDER, decode_member
from htdata.ingest.pipeline import load_pipeline
from htdata.inspect.preview import render_contact_sheet
from htdata.resources import PIPELINES_DIR
from htdata.settings import parse_setting
from htdata.store.episodeids import NoSuchEpisode
from htdata.store.indexfile import IndexDtypeError
from htdata.store.manifest import parse_manifest
from htdata.store.splitrule import SplitError
from tests.factories import PREVIEW_EPISODES, ingest_cli, write_synthetic_dataset


def test_every_class_in_errors_is_an_htdata_error():
    classes = [c for _, c in inspect.getmembers(errors, inspect.isclass)
               if issubclass(c, BaseException) and c.__module__ == errors.__name__]
    assert len(classes) >= 8
    assert all(issubclass(c, HtdataError) for c in classes)
    for kind in (ConfigError, ArgumentError, DatasetError):
        assert issubclass(kind, ValueError)
    assert issubclass(RecordMismatch, DatasetError)


def test_the_user_errors_defined_beside_their_code_are_htdata_types_too():
    for kind, base in ((NoSuchEpisode, ArgumentError), (MergeConflict, ArgumentError), (SplitError, ArgumentError),
                       (IndexDtypeError, DatasetError)):
        assert issubclass(kind, base) and issubclass(kind, ValueError)


def test_a_locked_dataset_is_an_htdata_error_caught_as_before():
    from htdata.store.lock import DatasetLocked

    assert issubclass(DatasetLocked, HtdataError) and issubclass(DatasetLocked, RuntimeError)
    assert not issubclass(DatasetLocked, ValueError)     # `except ValueError` never caught it: still does not


def _bad_pipeline(tmp_path):
    text = (PIPELINES_DIR / "native.toml").read_text().replace("max_skew_ms = 20", "max_skew_ms = -5")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


def test_bad_pipeline_setting_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="max_skew_ms"):
        load_pipeline(str(_bad_pipeline(tmp_path)))
    with pytest.raises(ConfigError, match="dotted.key=value"):
        parse_setting("no-equals-sign")


def test_bad_pipeline_setting_on_the_cli_is_one_line_exit_2(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    code = ingest_cli("--pipeline", str(_bad_pipeline(tmp_path)), str(src), str(tmp_path / "out"))
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("htdata ingest: error: ") and "max_skew_ms" in err


def test_wrong_arguments_are_argument_errors(tmp_path):
    with pytest.raises(ArgumentError, match="not a version"):
        parse_version("three")
    ds = write_synthetic_dataset(tmp_path / "ds", PREVIEW_EPISODES[:1])
    with pytest.raises(ArgumentError, match="no episode 'nope'"):
        render_contact_sheet(ds, episode="nope")


@pytest.mark.parametrize("suffix", [s for s in MEMBER_ORDER if s.endswith((".jpg", ".exr", ".npy"))] + ["json"])
def test_damaged_member_bytes_are_a_dataset_error(suffix):
    with pytest.raises(DatasetError, match="shard-000000-000.tar:k__000000"):
        decode_member(suffix, b"\xff\x00 not what the record says", "shard-000000-000.tar:k__000000")


def test_a_foreign_manifest_is_a_dataset_error():
    with pytest.raises(DatasetError, match="dataset.json: format 'other'"):
        parse_manifest(json.dumps({"format": "other", "format_version": 1}), "dataset.json")


def test_bad_handtouch_config_value_is_a_config_error(tmp_path):
    path = tmp_path / "train.toml"
    path.write_text('data_root = "d"\nout_dir = "o"\nrgb_encoder = "random:0"\n[model]\nencoder = "nope"\n')
    with pytest.raises(ConfigError, match=r"train.toml: model.encoder must be one of"):
        load_train_config(path)
