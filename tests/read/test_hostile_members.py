"""Issue 35 items 4, 5 and a rough edge: shard members whose shape is not the format's are refused by name.

An rgb.jpg member declaring 30000x30000 was served as a (30000,30000,3) array (~5.4 GB in a torch
dataset); an EXR member's forged window cost GBs before the shape check; a raw member of the wrong grid
failed with a message naming neither sample nor shard. Now each is one DatasetError naming the sample,
the JPEG and EXR refused from their headers, undecoded; `htdata validate` lists them as shape failures.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import htdata
from htdata.errors import DatasetError
from htdata.format.codec import encode_npy
from htdata.read.rawstream import RawMapRenderer
from htdata.validate import validate_dataset
from tests.factories import SPLIT_EPISODES, ingest_cli, make_native, write_synthetic_dataset
from tests.factories.hostile import forged_exr, forged_jpeg, peak_rss_mb, rewrite_members


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    return write_synthetic_dataset(tmp_path_factory.mktemp("pristine") / "ds", SPLIT_EPISODES[:2], seed=3)


@pytest.fixture
def ds(pristine, tmp_path):
    return shutil.copytree(pristine, tmp_path / "ds")


def _key(root, row: int) -> str:
    return htdata.open(root).read_sample(row, ("json",))[1]


def test_a_jpeg_member_declaring_30000x30000_is_refused_naming_the_sample_in_little_memory(ds):
    rewrite_members(ds, 2, {"rgb.jpg": forged_jpeg(30000, 30000)})
    key = _key(ds, 2)
    with pytest.raises(DatasetError, match=f"{key}.rgb.jpg: JPEG declares 30000x30000 pixels, expected 224x224: "
                                           f"not decoded"):
        htdata.open(ds).decoded(2)
    report = validate_dataset(ds, deep=True)
    [fail] = report["checks"]["content"]["failures"]
    assert (fail["what"], fail["key"], fail["found"]) == ("rgb_shape", key, "(30000, 30000)")
    code = f"""
import htdata
from htdata.errors import DatasetError
reader = htdata.open({str(ds)!r})
try:
    reader.decoded(2)
except DatasetError as exc:
    print("refused", exc)
"""
    out, peak = peak_rss_mb(code)
    assert f"{ds}: {key}.rgb.jpg: JPEG declares" in out and peak < 500, (out, peak)


@pytest.mark.parametrize("windows,said", [
    ((((0, 0), (19999, 19999)), ((0, 0), (19999, 19999))), "EXR display window (0, 0, 19999, 19999) is 20000x20000"),
    ((((0, 0), (0, 0)), ((0, 0), (199999, 199999))), "is 200000x200000, expected 224x224"),
])
def test_an_exr_member_with_a_forged_window_is_refused_by_reader_and_validate(ds, windows, said):
    hand = "right"
    rewrite_members(ds, 1, {f"tactile_{hand}.exr": forged_exr(*windows)})
    key = _key(ds, 1)
    with pytest.raises(DatasetError, match=f"{key}.tactile_{hand}.exr: ") as info:
        htdata.open(ds).decoded(1)
    assert said in str(info.value)
    report = validate_dataset(ds, deep=True)
    fails = [f for f in report["checks"]["content"]["failures"] if f["key"] == key]
    assert fails and fails[0]["what"] == "tactile_shape" and said in fails[0]["message"], fails


def test_a_raw_member_of_the_wrong_grid_names_the_sample(tmp_path):
    raw = make_native(tmp_path / "raw")
    ds = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, ds) == 0
    rewrite_members(ds, 3, {"raw_right.npy": encode_npy(np.zeros((1, 8, 8), np.float32))})
    key = _key(ds, 3)
    reader = htdata.open(ds)
    with pytest.raises(DatasetError, match=rf"{key}.raw_right.npy: raw rows shaped \(1, 8, 8\), expected "
                                           rf"\(R, 16, 16\)"):
        RawMapRenderer(reader).sample_map(3, "right")      # what the torch datasets serve from
    report = validate_dataset(ds, deep=True)
    lines = [f["message"] for f in report["checks"]["content"]["failures"]]
    assert any(f"sample {key}.raw_right.npy: raw rows shaped (1, 8, 8)" in line for line in lines), lines


@pytest.mark.parametrize("value", [60000.0, -1.0])
def test_a_resealed_map_outside_0_1_is_a_named_error_and_a_named_fail(ds, value):
    """Issue 44 item 6: a stored map of 1e38 (a float EXR) or -1 was served by the reader, and validate
    aborted with "'list' argument must have no negative elements". Written in the dataset's own pixel type
    (half here: 60000 is its 1e38), so that only the value rule can object."""
    from htdata.format.tactilecodec import EXR_PIXEL_TYPES, encode_exr

    reader = htdata.open(ds)
    hand = next(h for h in ("left", "right") if f"tactile_{h}.exr" in reader.read_sample(1)[2])
    bad = np.zeros((224, 224), np.float32)
    bad[100:110, 100:110] = value
    pixel = EXR_PIXEL_TYPES[reader.manifest["codec"].get("pixel_type", "half")]
    rewrite_members(ds, 1, {f"tactile_{hand}.exr": encode_exr(bad.astype(pixel), "zip", pixel)})
    key = _key(ds, 1)
    with pytest.raises(DatasetError, match=rf"{key}.*outside the format's \[0,1\]"):
        htdata.open(ds).decoded(1)
    report = validate_dataset(ds, deep=True)
    assert report["ok"] is False
    failures = [f for c in report["checks"].values() for f in c.get("failures", [])]
    assert any(key in f["message"] and "[0,1]" in f["message"] for f in failures), failures
