"""`htdata publish` never harms a dataset: its own, the one at the destination, or what it publishes (issue 35).

Fails on the code before issue 35: `publish DS file://DS` truncated every file of DS
and deleted its dataset.json; publishing into a folder holding another dataset
overwrote its version files (rc 0); a commit made while a publish ran left a
destination dataset.json naming a version whose files never went up; a source
damaged after a first publish deleted the remote dataset.json before failing; and
datasets that `htdata validate` refuses were published with rc 0.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import fsspec
import numpy as np
import pytest

from htdata.cli import main as cli_main
from htdata.errors import DatasetError
from htdata.read.reader import DatasetReader
from htdata.store import remote, storage
from htdata.store.destination import DestinationRefused
from htdata.store.versions import list_versions
from tests.factories import MIXED_HANDS_ONE_LAYOUT_EPISODES as EPISODES
from tests.factories import commit_split, ingest_cli, make_native, rewrite_manifest, write_synthetic_dataset
from tests.factories.legacy import as_format3


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(storage.CACHE_ENV, str(tmp_path / "cache"))


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Two datasets of the same shape but different identities (seed, creation), two versions each."""
    out = {}
    for name, seed, created in (("a", 3, "2001"), ("b", 4, "2002")):
        root = write_synthetic_dataset(tmp_path_factory.mktemp(name) / "ds", EPISODES, seed=seed, samples_per_shard=3)
        if created != "2001":   # a different first version: another dataset even where the content were equal
            manifest = json.loads((root / "versions" / "v000001.json").read_text())
            manifest["created"] = f"{created}-01-01T00:00:00+00:00"
            rewrite_manifest(root, manifest)
        commit_split(root, "main", {"train": ["ep_a", "ep_c"], "test": ["ep_b"]})
        out[name] = root
    return out


@pytest.fixture
def ds(made, tmp_path):
    return Path(shutil.copytree(made["a"], tmp_path / "work" / "ds", symlinks=True))


def _shards(root: Path) -> list[dict]:
    """The current version's shard entries, as a reader sees them (format 4 lists them in its segments)."""
    with DatasetReader(root) as reader:
        return reader.manifest["shards"]


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (relative path -> bytes), symlinks listed as links."""
    out = {}
    for path in sorted(folder.rglob("*")):
        if path.is_symlink():
            out[str(path.relative_to(folder))] = b"-> " + os.readlink(path).encode()
        elif path.is_file():
            out[str(path.relative_to(folder))] = path.read_bytes()
    return out


def remote_tree(url: str) -> dict[str, bytes]:
    fs, base = fsspec.core.url_to_fs(url)
    return {os.path.relpath(p, base): fs.cat_file(p) for p in fs.find(base)} if fs.exists(base) else {}


def memory_url() -> str:
    return f"memory://publish-{uuid.uuid4().hex}/ds"


def publish_cli(capsys, *argv) -> tuple[int, list[str]]:
    rc = cli_main(["publish", *map(str, argv), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    return rc, err


# -- 1. never into its own dataset --------------------------------------------------------------------------

@pytest.mark.parametrize("where", ["same", "file-url", "symlink", "inside", "inside-via-symlink", "holds",
                                   "dot-in-ds", "empty-file-url", "empty-path"])
def test_a_destination_overlapping_the_dataset_is_refused_and_nothing_written(ds, tmp_path, monkeypatch, capsys,
                                                                              where):
    link = tmp_path / "link"
    link.symlink_to(ds)
    before, outside_before = tree(ds), tree(tmp_path / "work")
    source, url = ds, {"same": str(ds), "file-url": f"file://{ds}", "symlink": f"file://{link}",
                       "inside": f"file://{ds}/published", "inside-via-symlink": f"{link}/shards/x",
                       "holds": f"file://{ds.parent}", "dot-in-ds": "file://.", "empty-file-url": "file://",
                       "empty-path": ""}[where]
    if where in ("dot-in-ds", "empty-file-url", "empty-path"):
        monkeypatch.chdir(ds)        # `cd DS && htdata publish . file://`
        source = Path(".")
    rc, err = publish_cli(capsys, source, url)
    assert rc == 2 and len(err) == 1 and err[0].startswith("htdata publish: error: "), err
    assert "nothing was written" in err[0]
    assert tree(ds) == before and tree(tmp_path / "work") == outside_before
    assert DatasetReader(ds).version == 2


def test_a_destination_inside_another_dataset_is_refused(ds, made, capsys):
    other = made["b"]
    before = tree(other)
    rc, err = publish_cli(capsys, ds, f"file://{other}/copy")
    assert rc == 2 and len(err) == 1 and f"inside the htdata dataset {other}" in err[0]
    assert tree(other) == before


# -- 2. never over another dataset; an older copy of this one is only added to ------------------------------

@pytest.mark.parametrize("kind", ["memory", "file"])
def test_publishing_over_another_dataset_is_refused_and_it_stays_whole(ds, made, tmp_path, capsys, kind):
    url = memory_url() if kind == "memory" else f"file://{tmp_path / 'site' / 'ds'}"
    remote.publish_dataset(made["b"], url)
    before = remote_tree(url)
    with pytest.raises(DestinationRefused, match="holds another htdata dataset .its version 1 differs"):
        remote.publish_dataset(ds, url)
    rc, err = publish_cli(capsys, ds, url)
    assert rc == 2 and len(err) == 1 and "publish never writes over another dataset" in err[0]
    assert remote_tree(url) == before
    far = DatasetReader(url)
    assert far.manifest == DatasetReader(made["b"]).manifest and far.sample(3) == DatasetReader(made["b"]).sample(3)


def test_a_destination_sharing_no_version_is_refused_as_unprovable(ds, made):
    url = memory_url()
    remote.publish_dataset(made["b"], url)
    fs, base = fsspec.core.url_to_fs(url)
    for n in (1, 2):   # as if the destination held only versions this dataset no longer has
        fs.mv(f"{base}/versions/v{n:06d}.json", f"{base}/versions/v{n + 7:06d}.json")
    fs.rm(f"{base}/dataset.json")
    fs.rm(f"{base}/.htdata-publish.json")
    with pytest.raises(DestinationRefused, match="shares no version with this dataset .it has v8..v9"):
        remote.publish_dataset(ds, url)


def test_a_folder_of_other_files_is_refused(ds, tmp_path, capsys):
    site = tmp_path / "home"
    site.mkdir()
    (site / "notes.txt").write_text("mine")
    rc, err = publish_cli(capsys, ds, f"file://{site}")
    assert rc == 2 and len(err) == 1 and "holds 1 file(s) (notes.txt, ...) but no htdata dataset" in err[0]
    assert tree(site) == {"notes.txt": b"mine"}
    (tmp_path / "afile").write_text("x")
    rc, err = publish_cli(capsys, ds, tmp_path / "afile")
    assert rc == 2 and "is a file, not a folder" in err[0]


def test_updating_an_older_copy_only_adds_and_keeps_every_version(ds, monkeypatch):
    url = memory_url()
    first = remote.publish_dataset(ds, url)
    assert first.version == 2 and first.kept == 0
    old = remote_tree(url)
    old_readers = {v: DatasetReader(url, version=v) for v in (1, 2)}
    snapshots = {v: [r.sample(i) for i in range(len(r))] for v, r in old_readers.items()}
    from htdata.curate.edit import remove_episodes

    remove_episodes(ds, ["ep_b"], dry_run=False, command="test: rm ep_b")   # version 3: re-packed shards
    commit_split(ds, "rule", {"train": ["ep_a"], "test": ["ep_c"]})    # version 4
    targets = []
    real = remote.upload_file
    monkeypatch.setattr(remote, "upload_file", lambda fs, local, target: targets.append(target) or
                        real(fs, local, target))
    second = remote.publish_dataset(ds, url)
    assert second.version == 4 and second.kept == len(old) - 2       # all but dataset.json and the marker
    now = remote_tree(url)
    pointers = ("dataset.json", ".htdata-publish.json")                # what names the newest version published
    assert {k: now[k] for k in old if k not in pointers} == {k: v for k, v in old.items() if k not in pointers}
    _, base = fsspec.core.url_to_fs(url)
    assert not [t for t in targets if os.path.relpath(t, base) in old]  # nothing already there was rewritten
    assert list_versions(url) == [1, 2, 3, 4]
    for v, samples in snapshots.items():
        r = DatasetReader(url, version=v)
        assert [r.sample(i) for i in range(len(r))] == samples
    assert [e["episode_id"] for e in DatasetReader(url).episodes] == ["ep_a", "ep_c"]
    again = remote.publish_dataset(ds, url)                          # up to date: nothing uploaded
    assert again.files == 0 and again.kept == second.kept + second.files - 1


def test_a_damaged_file_at_the_destination_is_replaced_with_the_recorded_bytes(ds):
    url = memory_url()
    remote.publish_dataset(ds, url)
    fs, base = fsspec.core.url_to_fs(url)
    name = _shards(ds)[1]["name"]
    good = fs.cat_file(f"{base}/shards/{name}")
    fs.pipe_file(f"{base}/shards/{name}", good[:-7] + b"garbage")
    result = remote.publish_dataset(ds, url)
    assert result.files == 1 and fs.cat_file(f"{base}/shards/{name}") == good


def test_a_newer_copy_at_the_destination_is_not_rolled_back(ds, tmp_path):
    newer = Path(shutil.copytree(ds, tmp_path / "newer"))
    commit_split(newer, "rule", {"train": ["ep_a"], "test": ["ep_c"]})   # version 3 of the same dataset
    url = memory_url()
    remote.publish_dataset(newer, url)
    before = remote_tree(url)
    with pytest.raises(DestinationRefused, match="already holds version 3 of this dataset, newer than its version 2"):
        remote.publish_dataset(ds, url)
    assert remote_tree(url) == before


# -- 7. one consistent snapshot; the source verified before the destination is touched -----------------------

def test_an_ingest_committing_while_publish_uploads_does_not_reach_the_destination(tmp_path, monkeypatch):
    raw = make_native(tmp_path / "raw")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, out) == 0                      # version 1
    make_native(tmp_path / "more")
    shutil.copytree(tmp_path / "more" / "rec_good", raw / "rec_two")
    real, commits = remote.upload_file, []

    def upload_racing_a_commit(fs, local, target):
        if not commits:   # deterministically between the snapshot and the first file of it going up
            commits.append(ingest_cli("--pipeline", "native", raw, out))          # version 2, dataset.json too
        return real(fs, local, target)

    monkeypatch.setattr(remote, "upload_file", upload_racing_a_commit)
    url = f"file://{tmp_path / 'site' / 'ds'}"
    result = remote.publish_dataset(out, url)
    assert commits == [0] and list_versions(out) == [1, 2] and json.loads((out / "dataset.json").read_text())[
        "version"] == 2
    assert result.version == 1
    site = tmp_path / "site" / "ds"
    assert (site / "dataset.json").read_bytes() == (out / "versions" / "v000001.json").read_bytes()
    assert not (site / "versions" / "v000002.json").exists() and not (site / "versions" / "v000002").exists()
    far, local = DatasetReader(url), DatasetReader(out, version=1)
    assert far.version == 1 and [far.sample(i) for i in range(len(far))] == [local.sample(i) for i in range(len(local))]
    monkeypatch.setattr(remote, "upload_file", real)
    later = remote.publish_dataset(out, url)                                       # the next publish takes v2
    assert later.version == 2 and later.kept > 0 and DatasetReader(url).version == 2
    assert len(DatasetReader(url)) == len(DatasetReader(out))


def test_a_source_damaged_after_a_first_publish_leaves_the_published_one_intact(ds, monkeypatch):
    url = memory_url()
    remote.publish_dataset(ds, url)
    commit_split(ds, "rule", {"train": ["ep_a"], "test": ["ep_c"]})     # something new to publish
    before = remote_tree(url)
    shard = ds / "shards" / _shards(ds)[0]["name"]
    data = bytearray(shard.read_bytes())
    data[700] ^= 0xFF
    shard.write_bytes(bytes(data))
    monkeypatch.setattr(remote, "upload_file", lambda *a: pytest.fail("uploaded before the source was verified"))
    with pytest.raises(DatasetError, match="sha256 differs from the manifest.*nothing was uploaded"):
        remote.publish_dataset(ds, url)
    assert remote_tree(url) == before and DatasetReader(url).version == 2


def test_a_killed_publish_resumes_adding_only_what_is_missing(ds, tmp_path):
    site = tmp_path / "site" / "ds"
    env = {**os.environ, "HTDATA_TEST_CRASH_AT": "publish_files_uploaded",
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, "-m", "htdata.cli", "publish", str(ds), f"file://{site}", "--quiet"],
                         env=env, capture_output=True, text=True)
    assert res.returncode == 137, res.stderr
    assert (site / "shards").is_dir() and not (site / "versions" / "v000002.json").exists()
    with pytest.raises(FileNotFoundError, match="no manifest"):     # files without their versions: no dataset yet
        DatasetReader(f"file://{site}")
    assert {".htdata-publish.json", ".lock"} <= set(tree(site))     # its marker, and its lock (the process died)
    kept = len([rel for rel in tree(site) if not rel.startswith(".")])
    result = remote.publish_dataset(ds, f"file://{site}")
    assert result.kept == kept and result.files == 3                 # only v1.json, v2.json and dataset.json went up
    assert not (site / ".lock").exists()                             # the dead publish's lock was taken over
    assert DatasetReader(site).manifest == DatasetReader(ds).manifest


# -- 9. what validate refuses is not published --------------------------------------------------------------

def _reseal(root: Path, manifest: dict, field: str, data: bytes) -> None:
    (root / manifest[field.replace("_sha256", "_file")]).write_bytes(data)
    manifest[field] = hashlib.sha256(data).hexdigest()
    rewrite_manifest(root, manifest)


def _wrong_offset(root: Path) -> None:
    manifest = json.loads((root / "dataset.json").read_text())
    index = np.load(root / manifest["index_file"])
    index["offset"][4] += 512
    buf = __import__("io").BytesIO()
    np.save(buf, index)
    _reseal(root, manifest, "index_sha256", buf.getvalue())


def _wrong_frame_count(root: Path) -> None:
    manifest = json.loads((root / "dataset.json").read_text())
    lines = (root / manifest["episodes_file"]).read_text().splitlines()
    record = json.loads(lines[0])
    record["num_frames"] += 1
    lines[0] = json.dumps(record)
    _reseal(root, manifest, "episodes_sha256", ("\n".join(lines) + "\n").encode())


def _miscounted_shard(root: Path) -> None:
    manifest = json.loads((root / "dataset.json").read_text())
    manifest["shards"][0]["samples"] += 1     # the manifest re-sealed by hand: no sha256 can tell
    rewrite_manifest(root, manifest)


def _garbled_rgb(root: Path) -> None:
    """Episode ep_a's first RGB frame (always decoded by the quick check) overwritten with as many bytes of
    garbage, its shard's sha256 re-sealed: only decoding can tell."""
    import io
    import tarfile

    manifest = json.loads((root / "dataset.json").read_text())
    shard = root / "shards" / manifest["shards"][0]["name"]
    data = bytearray(shard.read_bytes())
    with tarfile.open(fileobj=io.BytesIO(bytes(data))) as tar:
        member = next(m for m in tar.getmembers() if m.name.startswith("ep_a__000000.rgb"))
    data[member.offset_data:member.offset_data + member.size] = bytes(range(256)) * (member.size // 256) + \
        b"x" * (member.size % 256)
    shard.write_bytes(bytes(data))
    _reseal_shard_everywhere(root, shard.name, hashlib.sha256(bytes(data)).hexdigest())


def _reseal_shard_everywhere(root: Path, name: str, sha: str) -> None:
    """Every version file listing shard `name` made to record `sha` (and dataset.json, the newest's copy)."""
    for path in sorted((root / "versions").glob("v*.json")):
        manifest = json.loads(path.read_text())
        for shard in manifest["shards"]:
            if shard["name"] == name:
                shard["sha256"] = sha
        path.write_text(json.dumps(manifest, indent=2) + "\n")
    (root / "dataset.json").write_bytes(path.read_bytes())


@pytest.mark.parametrize("damage, named", [(_wrong_offset, "structure check"), (_wrong_frame_count, "structure check"),
                                           (_miscounted_shard, "structure check"), (_garbled_rgb, "content check")])
def test_a_version_validate_refuses_is_not_published(ds, capsys, damage, named):
    damage(as_format3(ds))      # the damages edit a format 3 version's own records (a segment's: test_segments.py)
    url = memory_url()
    rc, err = publish_cli(capsys, ds, url)
    assert rc == 2 and len(err) == 1 and "fails `htdata validate`, not published" in err[0], err
    assert named in err[0]
    assert remote_tree(url) == {}


def test_an_hdfs_url_without_a_jvm_is_one_line(ds, monkeypatch, capsys):
    def no_jvm(url, **kw):   # what pyarrow's HadoopFileSystem raises where no Java runtime is installed
        raise OSError("Unable to load libjvm\ndlopen(/usr/lib/jvm/default-java/libjvm.so) failed: no such file")

    monkeypatch.setattr(fsspec.core, "url_to_fs", no_jvm)
    rc, err = publish_cli(capsys, ds, "hdfs://namenode:8020/ds")
    assert rc == 2 and len(err) == 1
    assert err[0] == ("htdata publish: error: hdfs://namenode:8020/ds: the hdfs:// filesystem could not start: "
                      "Unable to load libjvm; hdfs:// needs a Java runtime and Hadoop's libhdfs, loaded by pyarrow "
                      "(set JAVA_HOME and HADOOP_HOME)")


def test_a_dataset_written_before_versions_publishes_and_updates_by_its_manifest(tmp_path, ds):
    old = as_format3(write_synthetic_dataset(tmp_path / "old", EPISODES, seed=5))
    manifest = json.loads((old / "dataset.json").read_text())    # as written before versions existed
    (old / manifest["episodes_file"]).rename(old / "episodes.jsonl")
    (old / manifest["index_file"]).rename(old / "index.npy")
    shutil.rmtree(old / "versions")
    for field in ("version", "parent", "change", "splits", "next_unit"):
        manifest.pop(field, None)
    manifest.update(format_version=1, episodes_file="episodes.jsonl", index_file="index.npy")
    (old / "dataset.json").write_text(json.dumps(manifest, indent=2))
    (old / "splits").mkdir()
    (old / "splits" / "main.json").write_text(json.dumps({"parts": {"train": {"episodes": ["ep_a"]}}}))
    url = memory_url()
    first = remote.publish_dataset(old, url)
    assert first.version == 0 and remote_tree(url)["splits/main.json"] == (old / "splits" / "main.json").read_bytes()
    assert DatasetReader(url).manifest == DatasetReader(old).manifest and len(DatasetReader(url)) == 10
    assert remote.publish_dataset(old, url).files == 0                            # the same dataset: up to date
    with pytest.raises(DestinationRefused, match=r"shares no version with this dataset \(it has unversioned"):
        remote.publish_dataset(ds, url)


def test_versions_recording_two_sha256_for_one_file_are_refused(ds):
    as_format3(ds)     # a format 4 version records a shard's sha256 in a segment, sealed by its own sha256
    name = json.loads((ds / "dataset.json").read_text())["shards"][0]["name"]
    manifest = json.loads((ds / "dataset.json").read_text())
    manifest["shards"][0]["sha256"] = "0" * 64        # the newest version only: v1 still records the true one
    rewrite_manifest(ds, manifest)
    url = memory_url()
    with pytest.raises(DatasetError, match=f"{name}: version 2 records sha256 000000000000, an earlier version"):
        remote.publish_dataset(ds, url)
    assert remote_tree(url) == {}
