"""Records that decide a served value are verified (issue 26 item 3), on a maps = "raw" dataset.

Every map such a dataset serves is rendered from its raw rows under the manifest's calibration and the
episode's `calibration_fit`. Editing either (and re-sealing the sha256 that covers the file) used to pass
`validate` and `validate --deep` and change every served map. Now a reader refuses to open the version
and validate fails, with one line naming the record; `validate --deep` also re-derives each episode
hand's taxels from the raw rows against the digest the ingest recorded.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import htdata
from htdata.cli import main as cli
from htdata.errors import DatasetError, RecordMismatch
from htdata.format.table import MANIFEST_FILE
from htdata.glove.calibration import decode_array, encode_array, fit_digest
from htdata.glove.layouts import load_layout
from htdata.store.manifest import load_manifest
from htdata.synthetic.formats.touchanything import TouchAnythingEpisode, write_touchanything_episode
from htdata.validate.validator import validate_dataset
from tests.factories import COLOURS, ingest_cli, rewrite_manifest
from tests.factories.legacy import reseal_records

LEFT = "touchanything_left_21x21"


@pytest.fixture(scope="module")
def raw_dataset(tmp_path_factory) -> Path:
    """Two TouchAnything episodes (both hands, values well above 0), left baseline fitted per episode."""
    tmp = tmp_path_factory.mktemp("records")
    rng = np.random.default_rng(3)
    for n in range(2):
        t = 8
        grids = {}
        for hand in ("left", "right"):
            lay = load_layout(f"touchanything_{hand}_21x21")
            g = np.full((t, 21, 21), np.nan, np.float32)
            g[:, lay.live_mask] = rng.uniform(0.2, 0.9, size=(t, int(lay.live_mask.sum()))).astype(np.float32)
            g[:, lay.bend_cells[:, 0], lay.bend_cells[:, 1]] = 0.25
            grids[hand] = g
        write_touchanything_episode(tmp / "ta" / "Home" / "pour" / f"2026032{n}_101010_00{n}",
                                    TouchAnythingEpisode(left_grid=grids["left"], right_grid=grids["right"],
                                                         chest_frames=[np.full((480, 640, 3), COLOURS[n], np.uint8)] * t,
                                                         ts_epoch_s=1.7e9 + np.arange(t) / 30.0), wrist_videos=False)
    out = tmp / "ds"
    assert ingest_cli("--pipeline", f"touchanything={tmp / 'ta'}", "--set", "tactile.maps=raw",
                      "--set", f"normalise.{LEFT}.baseline=rest_window", "--set", f"normalise.{LEFT}.rest_frames=4",
                      out) == 0
    return out


def _map_sum(root: Path) -> float:
    ds = htdata.open(root)
    return sum(float(m.sum(dtype=np.float64)) for i in range(len(ds)) for m in ds.decoded(i)["tactile"].values())


def _reseal_episodes(root: Path, edit) -> None:
    """Apply `edit` to the episode records, re-sealing every sha256 over them (tests/factories/legacy.py)."""
    reseal_records(root, edit)


def _scale_left_baseline(records: list[dict], reseal_digest: bool = False) -> None:
    fit = records[0]["calibration_fit"]["left"]
    arr = decode_array(fit["baseline"], (-1,), "test") * np.float32(0.5)     # plain or zlib: base64
    fit["baseline"] = encode_array(arr)
    if reseal_digest:
        records[0]["calibration_fit_sha256"]["left"] = fit_digest(fit)


def _failures(report: dict) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for check in report["checks"].values():
        for f in check["failures"]:
            out.setdefault(f["what"], []).append(f["message"])
    return out


def test_the_untouched_dataset_opens_and_validates_with_its_digests_checked(raw_dataset):
    ds = htdata.open(raw_dataset)
    ep = ds.episodes[0]
    assert set(ep["calibration_fit_sha256"]) == {"left"} and set(ep["taxels_sha256"]) == {"left", "right"}
    report = validate_dataset(raw_dataset, deep=True)
    assert report["ok"], _failures(report)
    assert report["checks"]["content"]["checked"]["taxel_digests"] == 4        # 2 episodes x 2 hands
    assert report["checks"]["structure"]["checked"]["calibration_records"] > 0


def test_a_halved_max_value_is_refused_by_open_and_validate(raw_dataset, tmp_path, capsys):
    copy = shutil.copytree(raw_dataset, tmp_path / "ds")
    before = _map_sum(copy)
    manifest = load_manifest(copy)
    cal_id = next(k for k, v in manifest["calibrations"].items() if v["layout"] == LEFT)
    manifest["calibrations"][cal_id]["max_value"] /= 2
    rewrite_manifest(copy, manifest)
    assert (copy / MANIFEST_FILE).read_bytes() == (copy / "versions" / "v000001.json").read_bytes()
    with pytest.raises(RecordMismatch, match=rf"v000001\.json: calibration {cal_id} \(layout '{LEFT}'\)"):
        htdata.open(copy)
    for deep in (False, True):
        failed = _failures(validate_dataset(copy, deep=deep))
        assert list(failed) == ["calibration_record"] and cal_id in failed["calibration_record"][0]
    capsys.readouterr()
    assert cli(["validate", str(copy)]) != 0
    assert cal_id in capsys.readouterr().out
    assert before > 0


def test_a_scaled_fitted_baseline_is_refused_by_open_and_validate(raw_dataset, tmp_path):
    copy = shutil.copytree(raw_dataset, tmp_path / "ds")
    _reseal_episodes(copy, _scale_left_baseline)
    with pytest.raises(RecordMismatch, match=r"(episodes|segments).*calibration_fit\.left: digest"):
        htdata.open(copy)
    for deep in (False, True):
        failed = _failures(validate_dataset(copy, deep=deep))
        assert list(failed) == ["calibration_record"], failed
        assert "calibration_fit.left" in failed["calibration_record"][0]


def test_deep_validate_rederives_the_taxels_when_the_fit_digest_is_resealed_too(raw_dataset, tmp_path):
    """Someone who also recomputes the fit's digest changes the served maps: only the taxel digest the
    ingest recorded can tell, by rendering every frame again from the raw rows."""
    copy = shutil.copytree(raw_dataset, tmp_path / "ds")
    before = _map_sum(copy)
    _reseal_episodes(copy, lambda records: _scale_left_baseline(records, reseal_digest=True))
    assert _map_sum(copy) != before                          # the served maps did change
    assert validate_dataset(copy)["ok"]                      # the sampled check cannot see it
    failed = _failures(validate_dataset(copy, deep=True))
    eid = htdata.open(copy).episodes[0]["episode_id"]
    assert list(failed) == ["taxels_sha256"] and len(failed["taxels_sha256"]) == 1
    assert eid in failed["taxels_sha256"][0] and "left" in failed["taxels_sha256"][0]


@pytest.mark.parametrize("removed", ["taxels_sha256", "calibration_fit_sha256"])
def test_a_digest_removed_from_a_record_is_a_failure_not_written_before_digests(raw_dataset, tmp_path, removed):
    """Issue 35: removing the digest (and re-sealing) made validate --deep skip the episode as if it had been
    written before digests existed. The manifest's record_digests says every record carries them."""
    copy = shutil.copytree(raw_dataset, tmp_path / "ds")
    assert load_manifest(copy)["record_digests"] == ["calibration_fit_sha256", "taxels_sha256"]
    eid = htdata.open(copy).episodes[0]["episode_id"]

    def drop(records):
        del records[0][removed]["left"]

    _reseal_episodes(copy, drop)
    said = rf"episode '{eid}' has no {removed} for left, which its version's manifest says every record carries"
    with pytest.raises(RecordMismatch, match=said):
        htdata.open(copy)
    failed = _failures(validate_dataset(copy, deep=True))
    assert any(re.search(said, line) for line in failed["calibration_record"]), failed
    manifest = load_manifest(copy)                  # a version written before record_digests existed
    del manifest["record_digests"]
    rewrite_manifest(copy, manifest)
    if removed == "taxels_sha256":
        assert validate_dataset(copy, deep=True)["ok"]     # nothing to check: as before


def test_trim_and_renormalise_keep_the_taxel_digests_true(raw_dataset, tmp_path):
    """A trimmed episode's digest covers its kept frames; a renormalised one, its new calibration."""
    from htdata.curate.edit import trim_episode

    copy = shutil.copytree(raw_dataset, tmp_path / "ds")
    eid = htdata.open(copy).episodes[0]["episode_id"]
    before = htdata.open(copy).episodes[0]["taxels_sha256"]
    trim_episode(copy, eid, "2:6", dry_run=False, command="trim")
    after = htdata.open(copy)
    assert after.episode_range(eid)[1] == 4
    assert set(after.episodes[after.episode_position(eid)]["taxels_sha256"]) == {"left", "right"}
    assert after.episodes[after.episode_position(eid)]["taxels_sha256"] != before
    report = validate_dataset(copy, deep=True)
    assert report["ok"], _failures(report)
    assert report["checks"]["content"]["checked"]["taxel_digests"] == 4
    assert cli(["renormalise", str(copy), "--pipeline", "touchanything",
                "--set", f"normalise.{LEFT}.baseline=rest_window", "--set", f"normalise.{LEFT}.rest_frames=2"]) == 0
    report = validate_dataset(copy, deep=True)
    assert report["ok"], _failures(report)
    assert report["checks"]["content"]["checked"]["taxel_digests"] == 4


def test_fitted_arrays_are_compressed_only_where_it_pays_and_always_decode():
    """A knot of one value over the grid (the pooled rest's shift) shrinks ~100x; a per-cell floor stays plain
    base64 (a stranger reads it with base64 + numpy); both decode exactly, and a damaged stream names its record."""
    from htdata.glove.calibration import ZLIB_PREFIX
    knots = np.repeat(np.float32([0.01, -0.02, 0.03])[:, None, None], 32 * 32, axis=1).reshape(3, 32, 32)
    floor = np.random.default_rng(0).uniform(0.001, 0.003, (32, 32)).astype(np.float32)
    packed, plain = encode_array(knots), encode_array(floor)
    assert packed.startswith(ZLIB_PREFIX) and len(packed) < knots.nbytes / 50
    assert not plain.startswith(ZLIB_PREFIX)
    assert np.array_equal(decode_array(packed, (-1, 32, 32), "ep"), knots)
    assert np.array_equal(decode_array(plain, (32, 32), "ep"), floor)
    with pytest.raises(DatasetError, match="ep calibration_fit.baseline: its zlib stream is incomplete"):
        decode_array(packed[:-8], (-1, 32, 32), "ep calibration_fit.baseline")
    with pytest.raises(DatasetError, match="ep calibration_fit.baseline: not a base64"):
        decode_array(ZLIB_PREFIX + "%%%%", (-1, 32, 32), "ep calibration_fit.baseline")
    with pytest.raises(DatasetError, match="bytes, expected 32x32 float32"):
        decode_array(packed, (32, 32), "ep")
