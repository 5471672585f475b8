import json
import shutil
import uuid
from pathlib import Path

import fsspec
import numpy as np
import pytest

from htdata.cli import main as cli_main
from htdata.read.reader import DatasetReader
from htdata.store import remote, storage
from htdata.store.segments import load_segment_index
from tests.factories import MIXED_HANDS_ONE_LAYOUT_EPISODES as EPISODES
from tests.factories import commit_split, write_synthetic_dataset
from tests.factories.legacy import as_format3


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = write_synthetic_dataset(tmp_path_factory.mktemp("ds") / "ds", EPISODES, seed=3,
                                   samples_per_shard=3, bend_dims=2)
    commit_split(root, "main", {"train": ["ep_a", "ep_c"], "test": ["ep_b"]})
    return root


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(storage.CACHE_ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def fresh_url() -> str:
    return f"memory://htdata-test-{uuid.uuid4().hex}/ds"


def test_publish_round_trip_is_byte_equal(dataset):
    url = fresh_url()
    result = remote.publish_dataset(dataset, url)
    versions = [json.loads(p.read_text()) for p in (dataset / "versions").glob("v*.json")]
    segment_files = {e[k] for v in versions for e in v["segments"] for k in ("records", "index")}
    # shards + each version's (manifest, splits) + the segments they list + layouts + dataset.json
    assert result.files == (len(DatasetReader(dataset).manifest["shards"]) + sum(1 + len(v["splits"]) for v in versions)
                            + len(segment_files) + len(list((dataset / "layouts").iterdir())) + 1)
    local, far = DatasetReader(dataset), DatasetReader(url)
    assert len(far) == len(local) == 10
    assert far.manifest == local.manifest and far.episodes == local.episodes
    for i in range(len(local)):
        assert far.sample(i) == local.sample(i)
    for (i, a), (j, b) in zip(local.iter_samples(), far.iter_samples(), strict=True):
        assert i == j and a == b
    w_local, w_far = local.window("ep_a", 4, 2), far.window("ep_a", 4, 2)
    for a, b in zip(w_local, w_far, strict=True):
        assert np.array_equal(a["rgb"], b["rgb"]) and a["meta"] == b["meta"]
        for hand in a["tactile"]:
            assert np.array_equal(a["tactile"][hand], b["tactile"][hand])
    assert far.split("main") == local.split("main")
    for layout_id in local.manifest["layouts"]:
        assert np.array_equal(far.coverage(layout_id), local.coverage(layout_id))
    fs = fsspec.filesystem("memory")
    assert not fs.exists(url.replace("memory://", "/") + "/.work")


def test_publish_keeps_the_versions_and_their_splits(dataset, tmp_path):
    import shutil

    from htdata.curate.split import make_split

    copy = Path(shutil.copytree(dataset, tmp_path / "copy"))
    make_split(copy, ["pour"], name="rule")                # version 3, beside the fixture's split of version 2
    url = fresh_url()
    remote.publish_dataset(copy, url)
    local, far = DatasetReader(copy), DatasetReader(url)
    assert far.version == local.version == 3 and far.split("rule") == local.split("rule")
    assert far.split("main") == local.split("main")
    assert DatasetReader(url, version=1).manifest == DatasetReader(copy, version=1).manifest


def _dropping_after(monkeypatch, n: int) -> None:
    """Make the n-th file upload fail as a dropped connection would."""
    real = remote.upload_file
    calls = {"n": 0}

    def failing_upload(fs, local, target):
        calls["n"] += 1
        if calls["n"] == n:
            raise ConnectionError("network dropped")
        return real(fs, local, target)

    monkeypatch.setattr(remote, "upload_file", failing_upload)


def test_interrupted_upload_leaves_no_manifest(dataset, monkeypatch, tmp_path):
    url = fresh_url()
    with monkeypatch.context() as m:
        _dropping_after(m, 4)
        with pytest.raises(ConnectionError):
            remote.publish_dataset(dataset, url)       # a first publish, interrupted
    fs, path = fsspec.core.url_to_fs(url)
    assert fs.exists(f"{path}/layouts")             # some files went up ...
    assert not fs.exists(f"{path}/dataset.json")    # ... but the URL is not a dataset
    with pytest.raises(FileNotFoundError, match="no manifest"):
        DatasetReader(url)
    resumed = remote.publish_dataset(dataset, url)  # the rerun adds only what is missing
    assert resumed.kept == 3 and DatasetReader(url).version == 2


def test_interrupted_update_leaves_the_previous_publish(dataset, monkeypatch, tmp_path):
    import shutil

    copy = Path(shutil.copytree(dataset, tmp_path / "copy"))
    url = fresh_url()
    remote.publish_dataset(copy, url)                  # version 2 is at the URL
    commit_split(copy, "more", {"train": ["ep_a"], "test": ["ep_b", "ep_c"]})     # version 3
    fs, path = fsspec.core.url_to_fs(url)
    pointer = fs.cat_file(f"{path}/dataset.json")
    with monkeypatch.context() as m:
        _dropping_after(m, 1)     # version 3 adds a split and its version file (its segments are version 2's)
        with pytest.raises(ConnectionError):
            remote.publish_dataset(copy, url)
    assert fs.cat_file(f"{path}/dataset.json") == pointer    # the URL still holds version 2, readable
    far = DatasetReader(url)
    assert far.version == 2 and far.sample(5) == DatasetReader(copy, version=2).sample(5)
    assert remote.publish_dataset(copy, url).version == 3 and DatasetReader(url).version == 3


def test_corrupt_local_shard_is_not_published(dataset, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    shard = sorted((copy / "shards").iterdir())[1]
    data = bytearray(shard.read_bytes())
    data[600] ^= 0xFF
    shard.write_bytes(bytes(data))
    url = fresh_url()
    with pytest.raises(ValueError, match="sha256 differs"):
        remote.publish_dataset(copy, url)
    fs, path = fsspec.core.url_to_fs(url)
    assert not fs.exists(f"{path}/dataset.json")


@pytest.mark.parametrize("stored_as", ["index.npy", "segments"])
def test_cached_index_is_reused_without_download(dataset, cache, monkeypatch, tmp_path, stored_as):
    if stored_as == "index.npy":
        dataset = as_format3(shutil.copytree(dataset, tmp_path / "v3"))
    url = fresh_url()
    remote.publish_dataset(dataset, url)
    first = DatasetReader(url)
    rows = first.index
    assert isinstance(rows, np.memmap)
    cached = list((cache / "index").glob("*/index.npy"))
    assert len(cached) == 1 and cached[0].parent.name == first.manifest["index_sha256"]
    mtime = cached[0].stat().st_mtime_ns
    # Remove the remote index (a format 4 version's index rows): a second open can only work from the cache.
    fs, path = fsspec.core.url_to_fs(url)
    for rel in ([first.stored["index_file"]] if stored_as == "index.npy" else
                [e["index"] for e in first.stored["segments"]]):
        fs.rm(f"{path}/{rel}")
    downloads = {"n": 0}
    real_open, real_read = remote.storage.open_binary, remote.storage.read_bytes

    def counting(real):
        def counted(location):
            if str(location).startswith("memory://") and str(location).endswith(".npy"):
                downloads["n"] += 1
            return real(location)
        return counted

    monkeypatch.setattr(remote.storage, "open_binary", counting(real_open))
    monkeypatch.setattr(remote.storage, "read_bytes", counting(real_read))
    second = DatasetReader(url)
    assert np.array_equal(np.asarray(second.index), np.asarray(rows))
    assert second.sample(7) == DatasetReader(dataset).sample(7)
    assert downloads["n"] == 0 and cached[0].stat().st_mtime_ns == mtime


@pytest.mark.parametrize("stored_as", ["index.npy", "segments"])
def test_cached_index_rejects_wrong_sha(dataset, cache, tmp_path, stored_as):
    if stored_as == "index.npy":
        dataset = as_format3(shutil.copytree(dataset, tmp_path / "v3"))
    url = fresh_url()
    remote.publish_dataset(dataset, url)
    manifest = json.loads((dataset / "dataset.json").read_text())
    manifest["index_sha256"] = "0" * 64
    with pytest.raises(ValueError, match="sha256"):
        if stored_as == "index.npy":
            remote.cached_index_path(url, manifest)
        else:
            load_segment_index(url, manifest)
    assert not [p for p in (cache / "index").rglob("*") if p.is_file()]     # no partial file left behind


def test_publish_refuses_uncommitted_directory(tmp_path):
    (tmp_path / "shards").mkdir()
    with pytest.raises(FileNotFoundError, match="no manifest"):
        remote.publish_dataset(tmp_path, fresh_url())


def test_publish_reports_each_verified_file(dataset):
    seen = []
    result = remote.publish_dataset(dataset, fresh_url(),
                                    on_file=lambda done, total, rel: seen.append((done, total, rel)))
    assert [d for d, _, _ in seen] == list(range(1, result.files + 1))
    assert {t for _, t, _ in seen} == {result.files} and seen[-1][2] == "dataset.json"


def test_publish_command(dataset, capsys):
    url = fresh_url()
    assert cli_main(["publish", str(dataset), url]) == 0
    assert "dataset.json" in capsys.readouterr().err     # per-file progress on stderr
    assert len(DatasetReader(url)) == 10
    assert cli_main(["publish", str(dataset / "missing"), fresh_url(), "--quiet"]) == 2
    assert "no manifest" in capsys.readouterr().err


@pytest.mark.parametrize("url, package, extra", [("s3://bucket/my-dataset", "s3fs", "s3"),
                                                 ("gs://bucket/ds", "gcsfs", "gcs"),
                                                 ("abfs://container/ds", "adlfs", "azure")])
def test_missing_backend_is_one_line_naming_what_to_install(dataset, monkeypatch, capsys, url, package, extra):
    monkeypatch.setitem(__import__("sys").modules, package, None)   # the backend is not installed
    assert cli_main(["publish", str(dataset), url, "--quiet"]) == 2          # publishing to it
    assert cli_main(["stats", url, "--brief"]) == 2                          # reading a dataset there
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "Traceback" not in "".join(err)
    for line, command in zip(err, ("publish", "stats")):
        assert line.startswith(f"htdata {command}: error: {url}")
        assert f"pip install {package}" in line and f"'.[{extra}]'" in line
    from htdata.errors import BackendMissing
    with pytest.raises(BackendMissing, match=f"needs the {package} package"):
        htdata_open(url)


def htdata_open(url):
    import htdata
    return htdata.open(url)
