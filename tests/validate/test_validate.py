"""htdata validate: a good dataset passes; each injected fault is caught and pinpointed."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from htdata.benchmarks.validation import validate_benchmark
from htdata.cli import main as cli_main
from htdata.curate.split import make_split, split_path
from htdata.errors import ArgumentError
from htdata.format.shardio import BLOCK
from htdata.format.table import EPISODES_FILE, FORMAT_VERSION, INDEX_FILE, MANIFEST_FILE, SHARDS_DIR
from htdata.format.tactilecodec import encode_exr
from htdata.store.manifest import load_episodes, load_index, load_records
from htdata.store.versions import VERSIONS_DIR
from htdata.validate import group_rows, validate_dataset
from tests.factories import FRAME_NS, edit_split, rewrite_manifest, write_synthetic_dataset
from tests.factories import SPLIT_EPISODES as EPISODES
from tests.factories.hostile import read_members, rewrite_members
from tests.factories.legacy import as_format3, reseal_index, reseal_records


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("pristine") / "ds", EPISODES, seed=1)


@pytest.fixture
def ds(pristine, tmp_path) -> Path:
    """A private copy each test may damage."""
    return Path(shutil.copytree(pristine, tmp_path / "ds"))


# -- fault injection helpers ---------------------------------------------------------------------

def _manifest(root: Path) -> dict:
    return json.loads((root / MANIFEST_FILE).read_text())


def _shards(root: Path) -> list[dict]:
    """The current version's shard entries, as a reader sees them (format 4 lists them in its segments)."""
    return load_records(root, _manifest(root))[0]["shards"]


def _index(root: Path) -> np.ndarray:
    """The current version's index rows (a writable copy)."""
    return load_index(root, mmap=False, manifest=_manifest(root)).copy()


def _episode_ids(root: Path) -> list[str]:
    return [e["episode_id"] for e in load_episodes(root, _manifest(root))]


def _unversioned(root: Path) -> Path:
    """Turn a (version 1) synthetic dataset into one written before versions existed (format_version 1):
    episodes.jsonl and index.npy at the root, no versions/, a manifest without version fields."""
    as_format3(root)
    manifest = _manifest(root)
    assert manifest["version"] == 1 and not manifest["splits"]
    (root / manifest["episodes_file"]).rename(root / EPISODES_FILE)
    (root / manifest["index_file"]).rename(root / INDEX_FILE)
    shutil.rmtree(root / VERSIONS_DIR)
    for field in ("version", "parent", "change", "splits", "next_unit"):
        manifest.pop(field, None)
    manifest.update(format_version=1, episodes_file=EPISODES_FILE, index_file=INDEX_FILE)
    (root / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2))
    return root


def _row_of(root: Path, episode_id: str, frame: int) -> int:
    eps = _episode_ids(root)
    index = _index(root)
    pos = eps.index(episode_id)
    return int(np.flatnonzero((index["episode"] == pos) & (index["frame"] == frame))[0])


def _failures(report: dict, check: str, what: str) -> list[dict]:
    return [f for f in report["checks"][check]["failures"] if f["what"] == what]


def _failing_checks(report: dict) -> set[str]:
    return {name for name, c in report["checks"].items() if c["failure_count"]}


# -- a sound dataset ------------------------------------------------------------------------------

def test_good_dataset_passes_every_check(ds, capsys):
    make_split(ds, ["pour"], test_ratio=0.3, seed=0, name="main")
    report = validate_dataset(ds, split="main", deep=True, workers=1)
    assert report["ok"], json.dumps({k: c["failures"][:3] for k, c in report["checks"].items()}, indent=1)
    s = report["checks"]["structure"]["checked"]
    assert s["samples"] == 16 and s["shards"] == len(_shards(ds))
    assert report["checks"]["content"]["checked"]["samples_decoded"] == 16
    assert report["checks"]["content"]["checked"]["tactile_maps_decoded"] == 20
    assert report["checks"]["splits"]["status"] == "pass"
    assert report["stats"]["frames_per_task"] == {"grasp": 4, "pour": 5, "wipe": 7}
    assert report["stats"]["frames_per_hand"] == {"left": 4, "right": 16}
    assert sum(report["stats"]["contact_area_histogram"]["counts"]) == 20
    assert sum(report["stats"]["pressure_histogram"]["counts"]) > 0

    assert cli_main(["validate", str(ds), "--split", "main"]) == 0
    out = capsys.readouterr().out
    assert "OK: dataset is sound" in out
    saved = json.loads((ds / "reports" / "validate.json").read_text())
    assert saved["ok"] is True and set(saved["checks"]) == {"structure", "content", "time", "sensors", "splits"}


def test_sampled_mode_decodes_a_seeded_subset_with_every_first_frame(ds):
    a = validate_dataset(ds, sample_frac=0.01, seed=3)
    b = validate_dataset(ds, sample_frac=0.01, seed=3)
    decoded = a["checks"]["content"]["checked"]["samples_decoded"]
    assert decoded == b["checks"]["content"]["checked"]["samples_decoded"]
    assert len(EPISODES) <= decoded < 16


def test_parallel_workers_agree_with_serial(ds):
    row = _row_of(ds, "ep_b", 2)
    nan_map = np.zeros((224, 224), np.float32)
    nan_map[5, 7] = np.nan
    rewrite_members(ds, row, {"tactile_left.exr": encode_exr(nan_map)})
    serial = validate_dataset(ds, deep=True, workers=1)
    parallel = validate_dataset(ds, deep=True, workers=2)
    assert parallel["params"]["workers"] == 2
    for name in serial["checks"]:
        assert serial["checks"][name]["failures"] == parallel["checks"][name]["failures"], name
        assert serial["checks"][name]["checked"] == parallel["checks"][name]["checked"], name


# -- structure faults -----------------------------------------------------------------------------

def test_flipped_byte_fails_shard_sha256(ds):
    shard = _shards(ds)[1]
    path = ds / SHARDS_DIR / shard["name"]
    data = bytearray(path.read_bytes())
    data[BLOCK + 700] ^= 0xFF  # inside the first sample's data: headers stay valid
    path.write_bytes(bytes(data))
    report = validate_dataset(ds)
    assert not report["ok"]
    [fail] = _failures(report, "structure", "shard_sha256")
    assert fail["shard"] == shard["name"]
    assert fail["expected"] == shard["sha256"]
    assert fail["found"] == hashlib.sha256(bytes(data)).hexdigest()
    assert cli_main(["validate", str(ds), "--json", str(ds / "r.json")]) == 1
    assert json.loads((ds / "r.json").read_text())["ok"] is False


def test_truncated_shard_names_size_and_lost_samples(ds):
    shard = _shards(ds)[0]
    path = ds / SHARDS_DIR / shard["name"]
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    report = validate_dataset(ds)
    [size] = _failures(report, "structure", "shard_size")
    assert size["shard"] == shard["name"] and size["expected"] == len(data) and size["found"] == len(data) // 2
    assert _failures(report, "structure", "shard_sha256")
    lost = _failures(report, "structure", "member_truncated")
    assert lost and all(f["shard"] == shard["name"] for f in lost)
    assert lost[-1]["key"] == "ep_a__000003"  # last sample of shard 0 (4 samples per shard)


def test_deleted_shard(ds):
    shard = _shards(ds)[2]
    (ds / SHARDS_DIR / shard["name"]).unlink()
    report = validate_dataset(ds)
    [fail] = _failures(report, "structure", "shard_missing")
    assert fail["shard"] == shard["name"]
    assert f"({shard['samples']} samples lost)" in fail["message"]


def test_extra_shard_is_a_failure_before_versions(ds):
    _unversioned(ds)
    assert validate_dataset(ds)["ok"]
    shutil.copy(ds / SHARDS_DIR / _shards(ds)[0]["name"], ds / SHARDS_DIR / "shard-999999-000.tar")
    report = validate_dataset(ds)
    [fail] = _failures(report, "structure", "shard_extra")
    assert fail["shard"] == "shard-999999-000.tar"


def test_shard_no_version_lists_is_a_warning(ds):
    # versioned: a shard no version lists is an interrupted write's leftover (htdata gc removes it)
    shutil.copy(ds / SHARDS_DIR / _shards(ds)[0]["name"], ds / SHARDS_DIR / "shard-999999-000.tar")
    report = validate_dataset(ds)
    assert report["ok"] and not _failures(report, "structure", "shard_extra")
    [warn] = [w for w in report["checks"]["structure"]["warnings"] if w["what"] == "shard_unlisted"]
    assert warn["shard"] == "shard-999999-000.tar"


def test_index_offset_pointing_at_the_wrong_member(ds):
    index = _index(ds)
    index[1]["offset"], index[2]["offset"] = index[2]["offset"], index[1]["offset"]
    _write_index(ds, index)
    report = validate_dataset(ds)
    fails = _failures(report, "structure", "member_offset")
    assert {f["key"] for f in fails} == {"ep_a__000001", "ep_a__000002"}
    assert fails[0]["expected"].startswith("ep_a__000001.json") and fails[0]["found"].startswith("ep_a__000002.json")
    assert not _failures(report, "structure", "index_sha256")


def _write_index(root: Path, index: np.ndarray) -> None:
    """Store `index` as the current version's, every sha256 over it re-sealed (tests/factories/legacy.py)."""
    reseal_index(root, lambda rows: rows.__setitem__(slice(None), index))


def test_swapped_index_rows_break_frame_order(ds):
    index = _index(ds)
    index[[1, 2]] = index[[2, 1]]           # ep_a frames 0,2,1,3,4
    _write_index(ds, index)
    report = validate_dataset(ds)
    [order] = _failures(report, "structure", "frame_order")
    assert (order["episode"], order["sample"], order["frame"], order["expected"]) == ("ep_a", 1, 2, 1)
    assert _failures(report, "structure", "offset_order")[0]["sample"] == 2


def test_interleaved_episodes_are_not_contiguous(ds):
    index = _index(ds)
    index[[4, 5]] = index[[5, 4]]           # ep_a frame 4 and ep_b frame 0 swap places
    _write_index(ds, index)
    report = validate_dataset(ds)
    fails = _failures(report, "structure", "episode_not_contiguous")
    assert {f["episode"] for f in fails} == {"ep_a", "ep_b"}
    assert not report["ok"]


def test_group_rows_handles_empty_groups():
    groups = group_rows(np.array([2, 0, 2, 0], np.uint32), 4)
    assert [g.tolist() for g in groups] == [[1, 3], [], [0, 2], []]


def test_tampered_episodes_file_fails_checksum(ds):
    as_format3(ds)
    path = ds / _manifest(ds)["episodes_file"]
    path.write_text(path.read_text().replace('"kitchen"', '"garage"', 1))
    report = validate_dataset(ds)
    [fail] = _failures(report, "structure", "episodes_sha256")
    assert fail["file"] == _manifest(ds)["episodes_file"] == "versions/v000001/episodes.jsonl"


def test_tampered_segment_records_fail_their_checksum(ds):
    entry = _manifest(ds)["segments"][0]
    path = ds / entry["records"]
    path.write_text(path.read_text().replace('"kitchen"', '"garage"', 1))
    report = validate_dataset(ds)
    [fail] = _failures(report, "structure", "segment_damaged")
    assert entry["records"] in fail["message"] and "sha256" in fail["message"]


def test_re_sealed_segment_records_that_disagree_with_the_manifest_fail(ds):
    # the segment's own sha256 re-sealed, the manifest's episodes_sha256 left as committed
    manifest = _manifest(ds)
    committed = manifest["episodes_sha256"]
    reseal_records(ds, lambda records: records[0].update(scene="garage"))
    manifest = _manifest(ds)
    manifest["episodes_sha256"] = committed
    rewrite_manifest(ds, manifest)
    report = validate_dataset(ds)
    assert _failures(report, "structure", "episodes_sha256")


def test_missing_manifest_is_reported_not_raised(tmp_path):
    report = validate_dataset(tmp_path)
    assert not report["ok"]
    assert _failures(report, "structure", "manifest_missing")
    assert report["checks"]["content"]["status"] == "skipped"



def test_validate_on_a_folder_that_is_no_dataset_writes_nothing_and_prints_one_line(tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "a.txt").write_text("not a dataset")
    assert cli_main(["validate", str(folder)]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.splitlines() == [
        f"htdata validate: FAIL manifest_missing: {folder / 'dataset.json'}: no dataset.json (not a committed dataset)"]
    assert sorted(p.name for p in folder.iterdir()) == ["a.txt"]      # no reports/ written into it


def test_validate_on_a_missing_folder_says_it_does_not_exist(tmp_path, capsys):
    gone = tmp_path / "datset"                  # a typo
    assert cli_main(["validate", str(gone)]) == 1
    assert capsys.readouterr().err.splitlines() == [f"htdata validate: FAIL manifest_missing: {gone}: no such folder"]
    assert not gone.exists()
    (tmp_path / "notes.txt").write_text("x")
    assert cli_main(["validate", str(tmp_path / "notes.txt")]) == 1
    assert "notes.txt: is a file, not a dataset folder" in capsys.readouterr().err


# -- content faults -------------------------------------------------------------------------------

def test_nan_tactile_frame_is_caught_only_by_content(ds):
    row = _row_of(ds, "ep_b", 2)
    nan_map = np.zeros((224, 224), np.float32)
    nan_map[5, 7] = np.nan
    rewrite_members(ds, row, {"tactile_left.exr": encode_exr(nan_map)})
    report = validate_dataset(ds, deep=True)
    assert _failing_checks(report) == {"content"}
    [fail] = _failures(report, "content", "tactile_nonfinite")
    assert (fail["key"], fail["episode"], fail["frame"], fail["hand"]) == ("ep_b__000002", "ep_b", 2, "left")
    assert "row 5, col 7" in fail["message"] and fail["found"] == "1 NaN, 0 Inf"


def test_out_of_range_and_float32_tactile(ds):
    big = np.full((224, 224), 0.5, np.float32)
    big[0, 0] = 1.5
    rewrite_members(ds, _row_of(ds, "ep_a", 1), {"tactile_right.exr": encode_exr(big)})
    rewrite_members(ds, _row_of(ds, "ep_c", 0),
                    {"tactile_right.exr": encode_exr(np.zeros((224, 224)), pixel_type=np.float32)})
    report = validate_dataset(ds, deep=True)
    [rng] = _failures(report, "content", "tactile_range")
    assert rng["key"] == "ep_a__000001" and rng["found"] == "[0.5, 1.5]"
    [shape] = _failures(report, "content", "tactile_shape")
    assert shape["key"] == "ep_c__000000" and "float32" in shape["found"]


def test_tactile_outside_coverage(tmp_path):
    cov = np.zeros((224, 224), np.uint8)
    cov[50:150, 50:150] = 1
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES[:2], coverages={"test_full": cov})
    assert validate_dataset(root, deep=True)["ok"]
    leak = np.zeros((224, 224), np.float32)
    leak[10, 20] = 0.3
    rewrite_members(root, _row_of(root, "ep_a", 4), {"tactile_right.exr": encode_exr(leak)})
    report = validate_dataset(root, deep=True)
    [fail] = _failures(report, "content", "tactile_outside_coverage")
    assert fail["key"] == "ep_a__000004" and "row 10, col 20" in fail["message"]


def test_undecodable_rgb(ds):
    rewrite_members(ds, _row_of(ds, "ep_d", 1), {"rgb.jpg": b"not a jpeg at all"})
    report = validate_dataset(ds, deep=True)
    [fail] = _failures(report, "content", "rgb_decode")
    assert fail["key"] == "ep_d__000001"


# -- time faults ----------------------------------------------------------------------------------

def _rewrite_json(root: Path, episode: str, frame: int, **changes) -> None:
    row = _row_of(root, episode, frame)
    meta = json.loads(read_members(root, row)["json"])
    meta.update(changes)
    rewrite_members(root, row, {"json": json.dumps(meta).encode()})


def test_non_monotonic_timestamps(ds):
    t1 = 1_000_000_000 + 1 * FRAME_NS
    _rewrite_json(ds, "ep_a", 3, t_rgb_ns=t1, t_tactile_ns={"right": t1 + 1000})
    report = validate_dataset(ds)
    assert _failing_checks(report) == {"time"}
    rgb = _failures(report, "time", "rgb_not_increasing")
    assert [(f["episode"], f["frame"], f["key"]) for f in rgb] == [("ep_a", 3, "ep_a__000003")]
    tac = _failures(report, "time", "tactile_not_increasing")
    assert [(f["frame"], f["hand"]) for f in tac] == [(3, "right")]


def test_sync_skew_over_tolerance(ds):
    t = 1_000_000_000 + 2 * FRAME_NS
    _rewrite_json(ds, "ep_c", 2, t_tactile_ns={"right": t - 25_000_000})  # 25 ms > 20 ms default
    report = validate_dataset(ds)
    [fail] = _failures(report, "time", "sync_skew")
    assert (fail["episode"], fail["frame"], fail["hand"], fail["found"]) == ("ep_c", 2, "right", 25_000_000)


def test_repeated_tactile_timestamp_is_a_warning_not_a_failure(ds):
    # a glove frame half-way between RGB frames 0 and 1 paired with both (skew 16.7 ms < 20 ms)
    t_mid = 1_000_000_000 + FRAME_NS // 2
    _rewrite_json(ds, "ep_a", 0, t_tactile_ns={"right": t_mid})
    _rewrite_json(ds, "ep_a", 1, t_tactile_ns={"right": t_mid})
    report = validate_dataset(ds)
    assert report["checks"]["time"]["failure_count"] == 0
    assert report["checks"]["time"]["warning_counts"]["tactile_repeated"] == 1


# -- sensors --------------------------------------------------------------------------------------

def test_all_zero_and_dead_regions_are_warnings(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES[:1])
    for frame in range(5):
        rewrite_members(root, _row_of(root, "ep_a", frame),
                        {"tactile_right.exr": encode_exr(np.zeros((224, 224), np.float32))})
    report = validate_dataset(root, deep=True)
    assert report["ok"]
    sensors = report["checks"]["sensors"]
    assert sensors["warning_counts"] == {"all_zero": 1}
    assert sensors["warnings"][0]["episode"] == "ep_a"


# -- split faults ---------------------------------------------------------------------------------

def test_episode_in_two_parts(ds):
    doc = make_split(ds, ["pour"], test_ratio=0.3, name="s")
    moved = doc["parts"]["train"]["episodes"][0]
    edit_split(ds, "s", lambda d: d["parts"]["test"]["episodes"].append(moved))
    report = validate_dataset(ds, split="s")
    [fail] = _failures(report, "splits", "episode_in_two_parts")
    assert fail["episode"] == moved and fail["found"] == ["train", "test"]
    assert _failures(report, "splits", "split_frames")  # stated test frames no longer add up


def test_ood_task_in_train(ds):
    make_split(ds, ["pour"], name="s")
    edit_split(ds, "s", lambda d: (d["parts"]["ood"]["episodes"].remove("ep_a"),
                                    d["parts"]["train"]["episodes"].append("ep_a")))
    report = validate_dataset(ds, split="s")
    leaks = _failures(report, "splits", "ood_task_leak")
    assert {(f["episode"], f.get("part")) for f in leaks} == {("ep_a", "train"), ("ep_a", None)}


def test_duplicated_frame_across_parts(ds):
    doc = make_split(ds, ["pour"], test_ratio=0.3, name="s")
    assert validate_dataset(ds, split="s")["ok"]
    ood_row = _row_of(ds, "ep_a", 2)             # ood part
    train_ep = next(e for e in doc["parts"]["train"]["episodes"] if e != "ep_b")
    train_row = _row_of(ds, train_ep, 0)
    source = read_members(ds, ood_row)
    rewrite_members(ds, train_row, {"rgb.jpg": source["rgb.jpg"], "tactile_right.exr": source["tactile_right.exr"]})
    report = validate_dataset(ds, split="s")
    assert _failing_checks(report) == {"splits"}
    [fail] = _failures(report, "splits", "duplicate_frame_across_parts")
    assert sorted(fail["keys"]) == sorted(["ep_a__000002", f"{train_ep}__000000"])
    assert fail["parts"] == ["ood", "train"]


def test_split_of_another_commit_and_unknown_split(ds):
    # versioned (format_version 2 of split files): a split names the episode records of the version it describes
    doc = make_split(ds, ["pour"], name="s")
    assert doc["format_version"] == 2 and FORMAT_VERSION == 4   # split files have their own version
    assert doc["episodes_sha256"] == _manifest(ds)["episodes_sha256"]
    assert validate_dataset(ds, split="s")["ok"]
    edit_split(ds, "s", lambda d: d.update(episodes_sha256="0" * 64))
    report = validate_dataset(ds, split="s")
    assert _failing_checks(report) == {"splits"}
    [fail] = _failures(report, "splits", "split_manifest")
    assert fail["expected"] == "0" * 64 and fail["found"] == _manifest(ds)["episodes_sha256"]
    with pytest.raises(ArgumentError, match=r"version 2 has no split 'nope' \(its splits: s\); nothing validated"):
        validate_dataset(ds, split="nope")       # a typo is said before validating (issue 35)
    split_path(ds, "s").unlink()                 # a known split whose file is gone: a failure of the report
    [fail] = _failures(validate_dataset(ds, split="s"), "splits", "split_missing")
    assert "known splits: s" in fail["message"]


def test_validate_split_typo_checks_the_name_first_and_keeps_the_saved_report(ds, capsys):
    """Issue 35: `validate --split typo` ran the whole validation, then failed, overwriting the saved report."""
    make_split(ds, ["pour"], name="main")
    assert cli_main(["validate", str(ds), "--split", "main"]) == 0
    saved = (ds / "reports" / "validate.json").read_bytes()
    capsys.readouterr()
    assert cli_main(["validate", str(ds), "--split", "mian", "--deep"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no split 'mian' (its splits: main)" in err[0], err
    assert (ds / "reports" / "validate.json").read_bytes() == saved


def test_split_file_edited_behind_the_manifest_fails_its_sha256(ds):
    make_split(ds, ["pour"], name="s")
    path = split_path(ds, "s")
    path.write_text(path.read_text().replace('"rule"', '"rule" ', 1))    # same document, other bytes
    report = validate_dataset(ds, split="s")
    [fail] = _failures(report, "splits", "split_sha256")
    assert fail["file"] == str(path) and fail["expected"] == _manifest(ds)["splits"]["s"]["sha256"]


def test_split_of_another_manifest_before_versions(ds):
    # unversioned (format_version 1): a split names the sha256 of the dataset.json it was made from
    _unversioned(ds)
    doc = make_split(ds, ["pour"], name="s")
    assert doc["format_version"] == 1 and split_path(ds, "s") == ds / "splits" / "s.json"
    assert validate_dataset(ds, split="s")["ok"]
    edit_split(ds, "s", lambda d: d.update(manifest_sha256="0" * 64))
    report = validate_dataset(ds, split="s")
    [fail] = _failures(report, "splits", "split_manifest")
    assert fail["expected"] == "0" * 64


def test_bad_arguments():
    with pytest.raises(ValueError, match="--sample-frac"):
        validate_dataset("x", sample_frac=0.0)
    with pytest.raises(ValueError, match="--workers must be >= 0"):
        validate_dataset("x", workers=-1)


def test_workers_have_one_meaning_0_is_this_process(pristine, monkeypatch):
    """htdata/workers.py: 0 (or 1) checks in this process; not given = every usable core with --deep."""
    from htdata.validate import shards, validator
    from htdata.validate.validator import ValidateConfig

    asked = []
    monkeypatch.setattr(validator, "run_jobs", lambda jobs, workers: asked.append(workers) or shards.run_jobs(jobs, 1))
    assert validate_dataset(pristine, workers=0, deep=True)["ok"] and asked == [1]     # 1: inline (run_jobs)
    monkeypatch.setattr(validator, "resolve_workers", lambda requested, default=None: 3 if default is None else 0)
    assert ValidateConfig(deep=True).resolved_workers(8) == 3 and ValidateConfig().resolved_workers(8) == 1
    assert ValidateConfig(deep=True).resolved_workers(2) == 2      # at most one process a shard


def test_validate_benchmark_reports_frames_per_second(pristine):
    result = validate_benchmark(pristine, workers=1)
    assert result["ok"] and result["frames"] == 16 and result["frames_per_s"] > 0


def test_regions_never_pressed_are_unexercised_by_name_not_dead():
    from htdata.validate.report import Check
    from htdata.validate.sensors import check_sensors

    means = [np.array([0.0, 0.0, 0.1 + 0.01 * f, 0.0]) for f in range(5)]   # ids 1 and 3 read 0 throughout
    sensor = {"ep_a:left": {"frames": list(range(5)), "region_means": means, "max": 0.2, "saturated": 0,
                            "covered": 100}}
    check = Check("sensors", 10)
    check_sensors(sensor, check, {1: "thumb.distal", 2: "thumb.proximal", 3: "index.distal"})
    assert dict(check.warning_counts) == {"unexercised_regions": 1}
    w = check.warnings[0]
    assert w["regions"] == ["thumb.distal", "index.distal"] and "dead" not in w["what"]
    assert "never pressed" in w["message"] and "thumb.distal, index.distal" in w["message"]


def test_a_json_report_that_cannot_be_written_is_an_error(tmp_path, capsys):
    ds = write_synthetic_dataset(tmp_path / "ds", EPISODES[:1])
    (tmp_path / "afile").write_text("x")
    for target in (tmp_path / "afile" / "r.json", Path("/proc/self/nope/r.json")):
        assert cli_main(["validate", str(ds), "--json", str(target)]) == 2
        assert "htdata validate: error: cannot write report" in capsys.readouterr().err
