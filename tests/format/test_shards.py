import hashlib
import io
import json
import tarfile

import numpy as np
import pytest

from htdata.benchmarks.index import index_load_benchmark
from htdata.format.shardio import ShardWriter, member_offsets, parse_key, sample_key
from htdata.format.table import EPISODES_FILE, INDEX_DTYPE, INDEX_FILE, MANIFEST_FILE
from htdata.resources import validate_json
from htdata.store.manifest import UnitResult, load_index, load_manifest, load_records
from htdata.store.parts import assemble, part_from_unit
from htdata.store.versions import version_dir, version_manifest_file
from tests.factories import write_synthetic_dataset

EPISODES = [
    {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": ("right",), "num_frames": 5},
    {"episode_id": "ep_b", "task": "wipe", "scene": "office", "hands": ("left", "right"), "num_frames": 3},
    {"episode_id": "ep_c", "task": "pour", "scene": "office", "hands": ("left",), "num_frames": 1},
]


def members(key, n=3, size=700):
    out = {"json": json.dumps({"key": key}).encode()}
    if n > 1:
        out["rgb.jpg"] = bytes([n]) * size
    if n > 2:
        out["tactile_right.exr"] = b"E" * 512  # exactly one block: no padding
    return out


def write_unit(directory, unit=0, n=5, per_shard=2):
    with ShardWriter(directory, unit=unit, samples_per_shard=per_shard) as w:
        for f in range(n):
            w.add_sample(sample_key("ep", f), members(sample_key("ep", f)))
    return w


def test_member_offsets_follow_ustar_rule():
    assert member_offsets(0, [1, 512, 513]) == [512, 1536, 2560]
    assert member_offsets(1024, []) == []


def test_writer_rolls_shards_and_records_offsets(tmp_path):
    w = write_unit(tmp_path)
    names = [s.name for s in w.shards]
    assert names == ["shard-000000-000.tar", "shard-000000-001.tar", "shard-000000-002.tar"]
    assert [s.samples for s in w.shards] == [2, 2, 1]
    assert [s.shard for s in w.samples] == [0, 0, 1, 1, 2]
    for s in w.shards:
        data = (tmp_path / s.name).read_bytes()
        assert hashlib.sha256(data).hexdigest() == s.sha256 and len(data) == s.bytes
    for rec in w.samples:
        with open(tmp_path / w.shards[rec.shard].name, "rb") as f:
            sizes = list(rec.sizes.values())
            for (suffix, size), off in zip(rec.sizes.items(), member_offsets(rec.offset, sizes)):
                f.seek(off)
                assert f.read(size) == members(rec.key)[suffix]
    assert not list(tmp_path.glob(".*tmp"))


def test_standard_tarfile_reads_members_in_design_order(tmp_path):
    w = write_unit(tmp_path, n=1)
    with tarfile.open(tmp_path / w.shards[0].name) as tf:
        infos = tf.getmembers()
    assert [i.name for i in infos] == ["ep__000000.json", "ep__000000.rgb.jpg", "ep__000000.tactile_right.exr"]
    for i in infos:
        assert (i.mtime, i.uid, i.gid, i.mode, i.uname, i.gname) == (0, 0, 0, 0o644, "", "")


def test_shards_are_byte_identical_for_equal_input(tmp_path):
    a, b = write_unit(tmp_path / "a"), write_unit(tmp_path / "b")
    assert [s.sha256 for s in a.shards] == [s.sha256 for s in b.shards]


def test_refuses_to_overwrite_finished_shard(tmp_path):
    write_unit(tmp_path)
    before = (tmp_path / "shard-000000-000.tar").read_bytes()
    with pytest.raises(FileExistsError, match="shard-000000-000.tar"):
        write_unit(tmp_path)
    assert (tmp_path / "shard-000000-000.tar").read_bytes() == before


def test_exception_mid_shard_leaves_no_partial_final_shard(tmp_path):
    with pytest.raises(RuntimeError):
        with ShardWriter(tmp_path, unit=3, samples_per_shard=2) as w:
            for f in range(3):
                w.add_sample(sample_key("ep", f), members(sample_key("ep", f)))
            raise RuntimeError("source died mid-shard")
    finals = sorted(p.name for p in tmp_path.iterdir())
    assert finals == ["shard-000003-000.tar"]  # the finished one only; temp of part 001 removed
    with tarfile.open(tmp_path / finals[0]) as tf:
        assert len(tf.getmembers()) == 6


def test_stale_temp_from_crashed_run_is_replaced(tmp_path):
    (tmp_path / ".shard-000000-000.tar.tmp").write_bytes(b"garbage")
    w = write_unit(tmp_path, n=1)
    assert (tmp_path / "shard-000000-000.tar").stat().st_size == w.shards[0].bytes
    assert not (tmp_path / ".shard-000000-000.tar.tmp").exists()


def test_member_name_limit_and_bad_input(tmp_path):
    with ShardWriter(tmp_path, unit=0, samples_per_shard=2) as w:
        long_key = sample_key("e" * 90, 123)      # long ids get a shortened, hashed stem
        assert long_key.startswith("e" * 47 + "-") and long_key.endswith("__000123")
        assert sample_key("e" * 90, 0) != sample_key("e" * 89 + "f", 0)
        w.add_sample(long_key, {"json": b"{}", "tactile_right.exr": b"x"})
        with pytest.raises(ValueError, match="unknown member"):
            w.add_sample(sample_key("ep", 0), {"json": b"{}", "depth.png": b"x"})
        with pytest.raises(ValueError, match="json"):
            w.add_sample(sample_key("ep", 0), {"rgb.jpg": b"x"})
        with pytest.raises(ValueError, match="non-empty"):
            w.add_sample(sample_key("ep", 0), {"json": b""})
        with pytest.raises(ValueError, match="invalid sample key"):
            w.add_sample("ep.0", {"json": b"{}"})
    with pytest.raises(ValueError, match="invalid sample key"):
        sample_key("bad.id", 1)
    assert parse_key("ep_x-1__000012") == ("ep_x-1", 12)


def test_max_shard_bytes_never_splits_a_sample(tmp_path):
    with ShardWriter(tmp_path, unit=0, samples_per_shard=100, max_shard_bytes=4096) as w:
        for f in range(4):
            w.add_sample(sample_key("ep", f), members(sample_key("ep", f)))
    assert sum(s.samples for s in w.shards) == 4 and len(w.shards) >= 2
    for s in w.shards:
        with tarfile.open(tmp_path / s.name) as tf:
            assert len(tf.getmembers()) == 3 * s.samples


def _stranger_shard_names(root) -> list[str]:
    """The current version's shards as someone without htdata finds them: dataset.json's segments, each a
    JSON file listing its units' shards (docs/FORMAT.md)."""
    manifest = json.loads((root / MANIFEST_FILE).read_text())
    return [s["name"] for e in manifest["segments"] for u in json.loads((root / e["records"]).read_text())["units"]
            for s in u["shards"]]


def test_webdataset_reads_our_shards(tmp_path):
    import webdataset as wds

    root = write_synthetic_dataset(tmp_path / "ds", EPISODES, samples_per_shard=3)
    urls = [str(root / "shards" / name) for name in _stranger_shard_names(root)]
    ds = wds.WebDataset(urls, shardshuffle=False, empty_check=False)
    got = [(s["__key__"], sorted(k for k in s if not k.startswith("__"))) for s in ds]
    keys = [f"{e['episode_id']}__{f:06d}" for e in EPISODES for f in range(e["num_frames"])]
    assert [k for k, _ in got] == keys
    assert got[0][1] == ["json", "rgb.jpg", "tactile_right.exr"]
    assert got[5][1] == ["json", "rgb.jpg", "tactile_left.exr", "tactile_right.exr"]


def test_commit_writes_consistent_index_and_manifest(tmp_path):
    root = write_synthetic_dataset(tmp_path / "ds", EPISODES, samples_per_shard=3)
    stored = load_manifest(root)
    manifest, episodes = load_records(root, stored)
    index = load_index(root, manifest=stored)
    assert index.dtype == INDEX_DTYPE
    assert manifest["counts"] == {"episodes": 3, "samples": 9, "shards": 4,
                                  "frames_per_hand": {"left": 4, "right": 8}}
    assert manifest["tasks"] == ["pour", "wipe"] and manifest["scenes"] == ["kitchen", "office"]
    assert (manifest["version"], manifest["parent"]) == (1, None) and stored["format_version"] == 4
    assert (root / version_manifest_file(1)).read_bytes() == (root / MANIFEST_FILE).read_bytes()
    assert not (root / INDEX_FILE).exists() and not (root / EPISODES_FILE).exists()
    assert not (root / version_dir(1) / INDEX_FILE).exists() and "shards" not in stored
    for entry in stored["segments"]:   # each segment file is sealed by the sha256 its manifest records
        for key in ("records", "index"):
            assert hashlib.sha256((root / entry[key]).read_bytes()).hexdigest() == entry[f"{key}_sha256"]
    assert hashlib.sha256("".join(json.dumps(e, sort_keys=True) + "\n" for e in episodes).encode()).hexdigest() \
        == stored["episodes_sha256"]
    buf = io.BytesIO()
    np.save(buf, np.asarray(index), allow_pickle=False)
    assert hashlib.sha256(buf.getvalue()).hexdigest() == stored["index_sha256"]
    assert _stranger_shard_names(root) == [s["name"] for s in manifest["shards"]]
    for s in manifest["shards"]:
        assert hashlib.sha256((root / "shards" / s["name"]).read_bytes()).hexdigest() == s["sha256"]
    assert [s["first_sample"] for s in manifest["shards"]] == [0, 3, 6, 8]
    assert [e["first_sample"] for e in episodes] == [0, 5, 8]
    assert episodes[0]["shards"] == ["shard-000000-000.tar", "shard-000000-001.tar"]
    for ep in episodes:
        validate_json(ep, "episode")
    # every index row points at the header of its sample's json member
    for row in index:
        shard = manifest["shards"][row["shard"]]["name"]
        with open(root / "shards" / shard, "rb") as f:
            f.seek(int(row["offset"]))
            header = tarfile.TarInfo.frombuf(f.read(512), "utf-8", "strict")
        key = f"{episodes[row['episode']]['episode_id']}__{int(row['frame']):06d}"
        assert header.name == key + ".json" and header.size == row["size_json"]
    assert (root / "layouts" / "coverage_test_full.png").is_file()
    assert (root / "layouts" / "regions.png").is_file()


def test_assemble_rejects_inconsistent_units(tmp_path):
    w = write_unit(tmp_path, n=3, per_shard=2)
    ep = {"episode_id": "ep", "task": "t", "scene": "s", "hands": ["right"], "layouts": {"right": "x"}}

    def build(*units):
        return assemble([part_from_unit(u) for u in units])

    built = build(UnitResult(0, w.shards, w.samples, [ep]))
    assert list(built.rows["frame"]) == [0, 1, 2] and built.episodes[0]["num_frames"] == 3
    with pytest.raises(ValueError, match="num_frames"):
        build(UnitResult(0, w.shards, w.samples, [{**ep, "num_frames": 4}]))
    with pytest.raises(ValueError, match="no episode record"):
        build(UnitResult(0, w.shards, w.samples, []))
    with pytest.raises(ValueError, match="expected frame 0"):
        build(UnitResult(0, w.shards, w.samples[1:], [ep]))


def test_missing_manifest_means_not_committed(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a committed"):
        load_manifest(tmp_path)


def test_index_load_benchmark_small(tmp_path):
    res = index_load_benchmark(10_000, tmp_path)
    assert res["rows"] == 10_000 and res["file_bytes"] > 10_000 * INDEX_DTYPE.itemsize
    assert res["probe_episode"] == 5000 // 500
    for k in ("mmap_load_ms", "full_load_ms", "mmap_rss_delta_mb", "full_rss_delta_mb"):
        assert np.isfinite(res[k])


def test_long_episode_ids_round_trip_and_webdataset_reads_them(tmp_path):
    import webdataset as wds

    from htdata.read.reader import DatasetReader

    long_id = "ot-" + "very_long_scene_name_" * 7 + "demo_1"           # 153 characters
    root = write_synthetic_dataset(tmp_path / "ds", [
        {"episode_id": long_id, "task": "pour", "scene": "lab", "hands": ("right",), "num_frames": 3},
        {"episode_id": "short", "task": "pour", "scene": "lab", "hands": ("right",), "num_frames": 2}])
    reader = DatasetReader(root)
    assert reader.episodes[0]["episode_id"] == long_id and reader.episode_range(long_id) == (0, 3)
    assert reader.decoded(2)["meta"]["episode_id"] == long_id
    keys = [s["__key__"] for name in sorted((root / "shards").glob("*.tar"))
            for s in wds.WebDataset(str(name), shardshuffle=False)]
    assert keys[:3] == [reader.key(i) for i in range(3)] and all(len(k) < 100 for k in keys)


def test_member_header_is_tarfiles_own_bytes():
    """The hand-filled USTAR header equals tarfile's for every name and size a shard can hold."""
    from htdata.format.shardio import _tarfile_header, member_header

    rng = np.random.default_rng(0)
    alphabet = list("abcXYZ019_-.é")
    names = ["a", "k__000001.json", "x" * 100, "é" * 50,
             "ta-Home-hook_carry-20260321_113311_723__000000.tactile_left.exr"]
    names += ["".join(rng.choice(alphabet, int(rng.integers(1, 45)))) for _ in range(300)]
    sizes = [0, 1, 511, 512, 513, 10629, 8**11 - 1] + [int(s) for s in rng.integers(0, 2**33, 20)]
    for name in names:
        for size in sizes:
            assert member_header(name, size) == _tarfile_header(name, size), (name, size)
    with pytest.raises(ValueError, match="longer than 100 bytes"):
        member_header("y" * 101, 1)
    with pytest.raises(ValueError):              # beyond 11 octal digits: tarfile's own refusal
        member_header("big", 8**11)


def test_sample_record_to_dict_is_asdict():
    import dataclasses

    from htdata.format.shardio import SampleRecord

    rec = SampleRecord(key="k__000001", shard=2, offset=1536, sizes={"json": 10, "rgb.jpg": 99})
    assert rec.to_dict() == dataclasses.asdict(rec) and rec.to_dict()["sizes"] is not rec.sizes
