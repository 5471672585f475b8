"""Source sha256 where the bytes are read (issue 37): the units hash, the driver checks and records.

Each source file of a run is hashed once, by the first unit that reads it; the driver opens no
source file; `--verify-sources` still fails every episode of a file that differs from its list
(also the episodes whose unit did not hash it) and commits nothing of their units.
"""

import hashlib
import json
import os
from pathlib import Path

from htdata.format.table import SHARDS_DIR, WORK_DIR
from htdata.ingest.pipeline import load_pipeline
from htdata.ingest.plan import Source, discover_sources, plan_units
from htdata.read.reader import DatasetReader
from tests.factories import (
    ingest_cli,
    ingest_crashing_at_unit,
    make_opentouch,
    make_two_scene_opentouch,
    small_pipeline,
)


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_sums(raw: Path) -> None:
    files = sorted(p for p in raw.rglob("*") if p.is_file() and p.name != "SHA256SUMS")
    (raw / "SHA256SUMS").write_text("".join(f"{sha(p)}  {p.relative_to(raw).as_posix()}\n" for p in files))


def test_each_source_file_is_hashed_once_per_run_by_the_first_unit_that_reads_it(tmp_path):
    raw = make_two_scene_opentouch(tmp_path / "raw")
    pipeline = load_pipeline(str(small_pipeline(tmp_path, "opentouch")))
    source = Source(pipeline=pipeline.with_maps(pipeline.tactile.maps.resolved(None)), root=raw.resolve())
    (refs,), failures = discover_sources([source])
    tasks = plan_units([(r, source) for r in sorted(refs, key=lambda r: r.episode_id)], tmp_path / "ds", 4)
    assert failures == [] and [t.unit for t in tasks] == [4, 5, 6, 7, 8]
    owners = {p: t.unit for t in tasks for p in t.hash_files}
    assert sum(len(t.hash_files) for t in tasks) == len(owners) == 3          # no file twice
    kitchen, office, table = (str((raw / n).resolve()) for n in ("home_kitchen_p1.hdf5", "office_desk_p2.hdf5",
                                                                  "annotations.csv"))
    assert owners == {kitchen: 4, table: 4, office: 7}      # each the first unit (in unit order) that reads it
    # the digests a resumed record holds are current: the owner's fingerprint covers its files' size and mtime
    before = tasks[0].fingerprint()
    os.utime(table, ns=(1, 1))
    assert tasks[0].fingerprint() != before and tasks[1].fingerprint() == plan_units(
        [(r, source) for r in sorted(refs, key=lambda r: r.episode_id)], tmp_path / "ds", 4)[1].fingerprint()


def test_the_driver_reads_no_source_byte_and_every_record_keeps_its_files_sha256(tmp_path, monkeypatch):
    from htdata.store import storage

    raw = make_two_scene_opentouch(tmp_path / "raw")
    opened = []
    real = storage.open_binary
    monkeypatch.setattr(storage, "open_binary", lambda path, *a, **k: (opened.append(str(path)), real(path, *a, **k))[1])
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, tmp_path / "ds", workers=1) == 0
    assert not [p for p in opened if str(raw.resolve()) in str(Path(p).resolve())], opened   # the workers hashed
    table = sha(raw / "annotations.csv")
    got = {e["episode_id"]: e["source_sha256"] for e in DatasetReader(tmp_path / "ds").episodes}
    assert got == {f"ot-{scene}-{demo}": {f"{scene}.hdf5": sha(raw / f"{scene}.hdf5"), "annotations.csv": table}
                   for scene, demos in (("home_kitchen_p1", ("demo_01", "demo_02", "demo_003")),
                                        ("office_desk_p2", ("demo_01", "demo_02")))
                   for demo in demos}
    report = json.loads((tmp_path / "ds" / "reports" / "ingest.json").read_text())
    assert report["timing"]["hash_s"] > 0


def test_a_damaged_shared_file_fails_every_unit_that_read_it_and_leaves_nothing_of_them(tmp_path):
    raw = make_two_scene_opentouch(tmp_path / "raw")
    write_sums(raw)
    office = raw / "office_desk_p2.hdf5"
    data = bytearray(office.read_bytes())
    data[-100] ^= 0x01                                    # one unit hashes it; both of its episodes read it
    office.write_bytes(bytes(data))
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, out) == 1      # some episodes failed
    report = json.loads((out / "reports" / "ingest.json").read_text())
    failed = {f["episode_id"]: f for f in report["failures"]}
    assert set(failed) == {"ot-office_desk_p2-demo_01", "ot-office_desk_p2-demo_02"}
    assert all(f["stage"] == "verify" and "differs from" in f["error"] and f["file"] == str(office)
               for f in failed.values())
    assert sorted(e["episode_id"] for e in DatasetReader(out).episodes) == [
        "ot-home_kitchen_p1-demo_003", "ot-home_kitchen_p1-demo_01", "ot-home_kitchen_p1-demo_02"]
    # units 3 and 4 (the office clips) left no shard and no record behind
    assert not list((out / SHARDS_DIR).glob("shard-00000[34]-*")) and not list((out / WORK_DIR).glob("unit-00000[34]*"))
    manifest = json.loads((out / "dataset.json").read_text())
    assert manifest["next_unit"] == 5                     # their numbers are not reused
    write_sums(raw)                                      # the list now describes these bytes: they go in
    assert ingest_cli("--pipeline", pipe, "--verify-sources", raw, out) == 0
    assert len(DatasetReader(out).episodes) == 5


def test_a_file_its_unit_could_not_hash_fails_every_episode_that_read_it(tmp_path, monkeypatch):
    import htdata.ingest.unit as unit

    raw = make_opentouch(tmp_path / "raw")
    table = str((raw / "annotations.csv").resolve())
    real = unit.sha256_file

    def unreadable(path, *a, **k):
        if str(path) == table:
            raise PermissionError(13, "Permission denied")
        return real(path, *a, **k)

    monkeypatch.setattr(unit, "sha256_file", unreadable)     # inline units (workers 0) see the patch
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, tmp_path / "ds") == 2
    report = json.loads((tmp_path / "ds" / "reports" / "ingest.json").read_text())
    assert len(report["failures"]) == 3 and all(
        f["stage"] == "verify" and "sha256 not available" in f["error"] and "Permission denied" in f["error"]
        and f["file"].endswith("annotations.csv") for f in report["failures"])


def test_a_resumed_owner_unit_gives_its_digests_to_the_units_run_after_it(tmp_path):
    raw = make_opentouch(tmp_path / "raw")
    pipe = small_pipeline(tmp_path, "opentouch")
    out = tmp_path / "ds"
    # unit 0 (demo_003) hashes both files and finishes; unit 2 (demo_02, run last) dies
    killed = ingest_crashing_at_unit(2, "--pipeline", pipe, raw, out)
    assert killed.returncode == 137, killed.stderr
    assert ingest_cli("--pipeline", pipe, raw, out) == 0
    report = json.loads((out / "reports" / "ingest.json").read_text())
    assert report["units_resumed"] == 2 and report["units_run"] == 1
    record = json.loads((out / WORK_DIR / "unit-000002.json").read_text())
    assert record["source_sha256"] == {}                 # the unit run now hashed nothing: unit 0's record did
    want = {"home_kitchen_p1.hdf5": sha(raw / "home_kitchen_p1.hdf5"), "annotations.csv": sha(raw / "annotations.csv")}
    assert [e["source_sha256"] for e in DatasetReader(out).episodes] == [want] * 3
