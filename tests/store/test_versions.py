"""Versions, parts and curation (rm / trim): every write is a new version, old versions stay readable."""

import json

import numpy as np
import pytest

from htdata.curate.edit import parse_frames, remove_episodes, resolve_episodes, trim_episode
from htdata.format.table import FORMAT_VERSION, MANIFEST_FILE
from htdata.read.reader import DatasetReader
from htdata.store.episodeids import NoSuchEpisode
from htdata.store.parts import assemble
from htdata.store.snapshot import commit_parts, open_snapshot
from htdata.store.versions import diff_episodes, list_versions, version_manifest_file
from tests.factories import write_synthetic_dataset

EPISODES = [
    {"episode_id": f"ep_{i}", "task": "pour" if i % 2 else "wipe", "scene": "lab", "hands": ("right",),
     "num_frames": 3 + i}
    for i in range(5)
]


def versioned(root, episodes=EPISODES):
    """A synthetic dataset: version 1, units of 2 episodes, shards of 4 samples."""
    return write_synthetic_dataset(root, episodes)


def all_samples(root, version=None):
    reader = DatasetReader(root, version=version)
    return {reader.key(i): reader.sample(i) for i in range(len(reader))}


def test_parts_round_trip_reassembles_the_same_index(tmp_path):
    root = versioned(tmp_path / "ds")
    snap = open_snapshot(root)
    parts = snap.parts()
    assert [p.unit for p in parts] == [0, 1, 2]
    built = assemble(parts)
    assert np.array_equal(built.rows, np.asarray(snap.index))
    assert built.episodes == snap.episodes
    assert built.shards == snap.manifest["shards"]


def test_first_version_and_log_fields(tmp_path):
    root = versioned(tmp_path / "ds")
    assert list_versions(root) == [1]
    manifest = json.loads((root / MANIFEST_FILE).read_text())
    assert manifest["version"] == 1 and manifest["parent"] is None and manifest["format_version"] == FORMAT_VERSION
    assert manifest["change"]["command"] == "commit"
    assert manifest["change"]["summary"] == {"episodes_added": 5, "episodes_removed": 0, "episodes_changed": 0,
                                             "frames_added": 25, "frames_removed": 0, "frames": 25}
    assert (root / version_manifest_file(1)).read_bytes() == (root / MANIFEST_FILE).read_bytes()
    assert [e["records"].split("/")[0] for e in manifest["segments"]] == ["segments"] * len(manifest["segments"])
    # the same episodes committed again on top: nothing added, nothing removed
    snap = open_snapshot(root)
    again = commit_parts(root, snap.parts(), {}, snap, "again")
    assert again["version"] == 2 and again["parent"] == 1
    assert again["change"]["summary"]["episodes_added"] == 0 and again["change"]["summary"]["frames"] == 25


def test_a_version_without_parent_counts_everything_added(tmp_path):
    import shutil

    src = write_synthetic_dataset(tmp_path / "src", EPISODES)
    snap = open_snapshot(src)
    fresh = tmp_path / "fresh"
    for sub in ("shards", "layouts"):
        shutil.copytree(src / sub, fresh / sub)
    fields = {k: snap.manifest[k] for k in ("sources", "layouts", "canonical", "codec")}
    manifest = commit_parts(fresh, snap.parts(), fields, None, "fresh")
    assert manifest["parent"] is None and manifest["change"]["summary"]["episodes_added"] == 5
    assert manifest["change"]["summary"]["frames_added"] == 25


def test_rm_makes_a_new_version_and_keeps_the_old_one_readable(tmp_path):
    root = versioned(tmp_path / "ds")
    before = all_samples(root)
    shards_before = {p.name: p.read_bytes() for p in (root / "shards").glob("*.tar")}
    edit, manifest = remove_episodes(root, ["ep_1"], dry_run=False, command="htdata rm ep_1")
    assert manifest["version"] == 2 and manifest["parent"] == 1
    assert edit.removed == ["ep_1"] and edit.repacked_units == [0] and edit.frames_removed == 4
    after = all_samples(root)
    assert not any(k.startswith("ep_1__") for k in after)
    assert {k: v for k, v in before.items() if not k.startswith("ep_1__")} == after   # bytes copied, not re-encoded
    assert all_samples(root, version=1) == before                                   # old version intact
    for name, data in shards_before.items():                                         # nothing rewritten in place
        assert (root / "shards" / name).read_bytes() == data
    diff = diff_episodes(open_snapshot(root, 1).episodes, open_snapshot(root, 2).episodes)
    assert diff["removed"] == ["ep_1"] and diff["added"] == [] and diff["changed"] == []


def test_rm_dry_run_writes_nothing(tmp_path):
    root = versioned(tmp_path / "ds")
    files = sorted(p.relative_to(root) for p in root.rglob("*"))
    edit, manifest = remove_episodes(root, ["ep_[23]"], dry_run=True, command="htdata rm --dry-run")
    assert manifest is None and edit.removed == ["ep_2", "ep_3"]
    assert "remove episode ep_2" in edit.lines() and any("shard-000001" in line for line in edit.lines())
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == files


def test_rm_of_a_whole_unit_drops_it_without_repacking(tmp_path):
    root = versioned(tmp_path / "ds")
    edit, manifest = remove_episodes(root, ["ep_2", "ep_3"], dry_run=False, command="rm")
    assert edit.repacked_units == [] and manifest["counts"]["episodes"] == 3
    assert not any(s["name"].startswith("shard-000001-") for s in manifest["shards"])


def test_typo_is_an_error_with_near_matches(tmp_path):
    root = versioned(tmp_path / "ds")
    with pytest.raises(NoSuchEpisode, match=r"no episode matches 'ep_7'.*did you mean"):
        remove_episodes(root, ["ep_7"], dry_run=False, command="rm")
    with pytest.raises(NoSuchEpisode, match="no episode matches 'zz\\*'"):
        resolve_episodes(["ep_1"], ["zz*"])
    assert list_versions(root) == [1]


def test_trim_renumbers_frames_and_keeps_source_time(tmp_path):
    root = versioned(tmp_path / "ds")
    old = DatasetReader(root)
    first, n = old.episode_range("ep_4")
    assert n == 7
    edit, manifest = trim_episode(root, "ep_4", "2:5", dry_run=False, command="trim")
    reader = DatasetReader(root)
    start, m = reader.episode_range("ep_4")
    assert m == 3 and edit.frames_removed == 4
    for k in range(3):
        meta = reader.decoded(start + k)["meta"]
        old_meta = old.decoded(first + 2 + k)["meta"]
        assert meta["frame_index"] == k and meta["key"] == f"ep_4__{k:06d}"
        assert reader.sample(start + k)["rgb.jpg"] == old.sample(first + 2 + k)["rgb.jpg"]
        assert {k2: v for k2, v in meta.items() if k2 not in ("key", "frame_index")} == \
               {k2: v for k2, v in old_meta.items() if k2 not in ("key", "frame_index")}
    record = reader.episodes[reader.episode_position("ep_4")]
    assert record["trimmed"] == {"start": 2, "stop": 5, "of": 7}
    with pytest.raises(ValueError, match="non-empty range"):
        parse_frames("5:5", 7, "ep_4")
    with pytest.raises(ValueError, match="A:B"):
        parse_frames("2-5", 7, "ep_4")


def test_splits_carry_over_removed_episodes_leave_their_part(tmp_path):
    from htdata.curate.split import make_split

    root = versioned(tmp_path / "ds")
    make_split(root, ["pour"], name="main", seed=0)        # version 2
    v1 = DatasetReader(root).split("main")
    remove_episodes(root, ["ep_1"], dry_run=False, command="rm")
    v2 = DatasetReader(root).split("main")
    assert "ep_1" in v1["parts"]["ood"]["episodes"] and "ep_1" not in v2["parts"]["ood"]["episodes"]
    for part in ("train", "test"):
        assert v2["parts"][part]["episodes"] == v1["parts"][part]["episodes"]
    assert v2["carried"] == {"from_version": 2, "left": ["ep_1"], "unassigned": []}
    assert DatasetReader(root, version=2).split("main")["parts"] == v1["parts"]


def test_gc_keeps_current_and_frees_unlisted_shards(tmp_path):
    from htdata.curate.gc import collect

    root = versioned(tmp_path / "ds")
    remove_episodes(root, ["ep_0"], dry_run=False, command="rm")       # re-packs unit 0 -> unit 3
    v2_shards = {s["name"] for s in open_snapshot(root).manifest["shards"]}
    plan = collect(root, keep_versions=1, dry_run=True, command="gc", retention_s=0, force=True)
    assert plan.dropped_versions == [1] and {n for n, _ in plan.dropped_shards} == {"shard-000000-000.tar",
                                                                                     "shard-000000-001.tar"}
    assert list_versions(root) == [1, 2]                                # dry run: nothing deleted
    plan = collect(root, keep_versions=1, dry_run=False, command="gc", retention_s=0, force=True)
    assert plan.bytes_freed > 0 and list_versions(root) == [2]
    assert {p.name for p in (root / "shards").glob("*.tar")} == v2_shards
    assert len(all_samples(root)) == 25 - 3
    with pytest.raises(FileNotFoundError, match="version 1 was removed by `gc`"):
        DatasetReader(root, version=1)
    with pytest.raises(ValueError, match="keep-versions must be >= 1"):
        collect(root, keep_versions=0, dry_run=True, command="gc")


def test_merge_links_shards_dedupes_identical_and_refuses_conflicts(tmp_path):
    from htdata.curate.merge import MergeConflict, merge

    a = versioned(tmp_path / "a", EPISODES[:3])
    b = versioned(tmp_path / "b", EPISODES[2:])           # ep_2 in both, identical content
    report = merge(a, b, tmp_path / "out", "merge")
    assert report.deduplicated == ["ep_2"] and report.copied + report.linked > 0
    merged = all_samples(tmp_path / "out")
    assert merged == {**all_samples(a), **all_samples(b)}
    assert report.manifest["version"] == 1 and report.manifest["counts"]["episodes"] == 5
    # with itself: everything is a duplicate
    self_merge = merge(a, a, tmp_path / "self", "merge")
    assert all_samples(tmp_path / "self") == all_samples(a) and len(self_merge.deduplicated) == 3
    # same id, different content
    other = EPISODES[:1] + [{**EPISODES[1], "num_frames": 9}]
    c = versioned(tmp_path / "c", other)
    with pytest.raises(MergeConflict, match="'ep_1' is in both datasets with different content"):
        merge(a, c, tmp_path / "bad", "merge")
    with pytest.raises(MergeConflict, match="not empty"):
        merge(a, b, tmp_path / "out", "merge")


def test_log_and_diff_commands(tmp_path, capsys):
    from htdata.cli import main

    root = versioned(tmp_path / "ds")
    assert main(["rm", str(root), "ep_1", "--dry-run"]) == 0
    assert "would remove episode ep_1" in capsys.readouterr().out
    assert main(["rm", str(root), "ep_1"]) == 0
    assert main(["trim", str(root), "ep_4", "--frames", "1:3"]) == 0
    capsys.readouterr()
    assert main(["log", str(root)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 4 and out[-1].startswith("* v3") and "htdata trim ep_4 --frames 1:3" in out[-1]
    assert "+0/-0/~1 episodes  +0/-5 frames" in out[-1]        # a trimmed episode's lost frames count
    assert "-1/~0 episodes" in out[-2]
    assert main(["diff", str(root), "1", "3"]) == 0
    out = capsys.readouterr().out
    assert "- ep_1" in out and "~ ep_4" in out and "1 removed, 1 changed" in out
    assert main(["rm", str(root), "ep_9"]) == 2
    assert "did you mean" in capsys.readouterr().err


def test_every_version_validates_and_a_damaged_version_file_is_named(tmp_path):
    from htdata.curate.split import write_split
    from htdata.validate import validate_dataset

    root = versioned(tmp_path / "ds")
    result = write_split(root, ["pour"], name="main", seed=0)               # v2: a split-only version
    assert result.version == 2 and result.path == root / "versions/v000002/splits/main.json"
    remove_episodes(root, ["ep_1"], dry_run=False, command="rm")            # v3: ep_1 leaves ood
    trim_episode(root, "ep_4", "0:2", dry_run=False, command="trim")        # v4
    for v in (1, 2, 3, 4):
        report = validate_dataset(root, split="main" if v > 1 else None, deep=True, workers=1, version=v)
        assert report["ok"], (v, {k: c["failures"] for k, c in report["checks"].items() if c["failures"]})
    warned = validate_dataset(root, split="main", version=3)["checks"]["splits"]["warnings"]
    assert any(w["what"] == "split_episodes_left" for w in warned)
    # a truncated version file: validate names it; the other versions still open and validate
    path = root / "versions/v000002.json"
    path.write_bytes(path.read_bytes()[:100])
    bad = validate_dataset(root, version=2)
    assert not bad["ok"] and "versions/v000002.json" in bad["checks"]["structure"]["failures"][0]["message"]
    assert validate_dataset(root, version=3)["ok"] and len(DatasetReader(root, version=1)) == 25
    path.unlink()
    gone = validate_dataset(root, version=2)
    assert not gone["ok"] and "no version 2" in gone["checks"]["structure"]["failures"][0]["message"]


def test_split_update_keeps_parts_and_reports_changes(tmp_path):
    from htdata.curate.split import SplitError, write_split

    root = versioned(tmp_path / "ds")
    first = write_split(root, ["pour"], name="main", seed=0)
    assert sum(map(len, first.gained.values())) == 5 and not any(first.lost.values())
    remove_episodes(root, ["ep_2"], dry_run=False, command="rm")        # the carried split already lost ep_2
    assert DatasetReader(root).split("main")["carried"]["left"] == ["ep_2"]
    again = write_split(root, ["pour"], name="main", seed=0)
    assert not any(again.gained.values()) and not any(again.lost.values())
    assert again.doc["parts"] == {p: {**v} for p, v in DatasetReader(root).split("main")["parts"].items()}
    with pytest.raises(SplitError, match="exists with other params"):
        write_split(root, ["wipe"], name="main", seed=0)
    forced = write_split(root, ["wipe"], name="main", seed=0, force=True)
    assert set(forced.doc["parts"]["ood"]["episodes"]) == {"ep_0", "ep_4"}
    assert DatasetReader(root, version=again.version).split("main")["params"]["ood_tasks"] == ["pour"]


def test_split_again_with_nothing_new_makes_no_version(tmp_path):
    from htdata.curate.split import write_split

    root = versioned(tmp_path / "ds")
    first = write_split(root, ["pour"], name="main", seed=0)
    again = write_split(root, ["pour"], name="main", seed=0)
    assert again.version == first.version == 2 and list_versions(root) == [1, 2]
    assert again.doc == first.doc and again.path == first.path


def test_commands_that_change_nothing_commit_nothing_and_say_so(tmp_path, capsys):
    from htdata.cli import main as cli_main

    root = versioned(tmp_path / "ds")
    split = ["split", str(root), "--ood-task", "pour", "--name", "main"]
    assert cli_main(split) == 0 and list_versions(root) == [1, 2]
    capsys.readouterr()
    for again in (split, split + ["--force"]):     # same name and params, with or without --force
        assert cli_main(again) == 0
        assert capsys.readouterr().out.startswith("nothing changed: version 2 stays current")
    n = {e["episode_id"]: e["num_frames"] for e in DatasetReader(root).episodes}["ep_1"]
    assert cli_main(["trim", str(root), "ep_1", "--frames", f"0:{n}"]) == 0   # keeps every frame
    assert "nothing changed: version 2 stays current" in capsys.readouterr().out
    assert list_versions(root) == [1, 2]


def test_a_split_carried_unchanged_by_another_split_is_not_committed_again(tmp_path, capsys):
    """Issue 35: `htdata split --name main` re-run after another split was committed made a +0/-0 version
    (make lerobot-check and the smoke each added one): main is carried unchanged, so nothing changes."""
    from htdata.cli import main as cli_main

    root = versioned(tmp_path / "ds")
    main = ["split", str(root), "--ood-task", "pour", "--name", "main", "--force"]
    assert cli_main(main) == 0
    assert cli_main(["split", str(root), "--ood-task", "pour", "--name", "other", "--seed", "3"]) == 0
    assert list_versions(root) == [1, 2, 3]
    capsys.readouterr()
    assert cli_main(main) == 0
    assert capsys.readouterr().out.startswith("nothing changed: version 3 stays current")
    assert list_versions(root) == [1, 2, 3]
    remove_episodes(root, ["ep_1"], dry_run=False, command="rm")     # main carried with an episode gone:
    assert cli_main(main) == 0 and list_versions(root) == [1, 2, 3, 4, 5]   # re-made, it says so no more


def test_a_write_built_on_a_stale_parent_is_refused(tmp_path):
    root = versioned(tmp_path / "ds")
    stale = open_snapshot(root)
    remove_episodes(root, ["ep_1"], dry_run=False, command="rm")          # version 2 is current now
    with pytest.raises(RuntimeError, match="current version is 2, this write was built on 1"):
        commit_parts(root, stale.parts(), {}, stale, "late writer")
    with pytest.raises(RuntimeError, match="current version is 2, this write was built on None"):
        commit_parts(root, stale.parts(), {k: stale.manifest[k] for k in ("sources", "layouts", "canonical",
                                                                           "codec")}, None, "fresh?")
    assert list_versions(root) == [1, 2] and len(DatasetReader(root)) == 25 - 4


def test_gc_also_drops_stats_cache_entries_no_kept_version_uses(tmp_path):
    from htdata.curate.gc import collect
    from htdata.format.table import STATS_DIR
    from htdata.inspect.stats import episode_key, episode_stats
    from tests.factories.tactile import clean_series, write_taxel_dataset

    glove = "opentouch_right_16x16"
    root = write_taxel_dataset(tmp_path / "ds", [          # one work unit per episode
        {"episode_id": f"ep_{i}", "task": "pour", "scene": "lab", "hands": {"right": (glove, clean_series(glove, 6, i))}}
        for i in range(3)])
    with DatasetReader(root) as reader:
        episode_stats(reader, cache_dir=root / STATS_DIR)
    assert len(list((root / STATS_DIR).iterdir())) == 3
    remove_episodes(root, ["ep_0"], dry_run=False, command="rm")
    with DatasetReader(root) as reader:
        current = {f"{episode_key(reader, p)}.json" for p in range(len(reader.episodes))}
    assert collect(root, keep_versions=2, dry_run=True, command="gc", retention_s=0, force=True).dropped_stats == []   # version 1 uses it
    plan = collect(root, keep_versions=1, dry_run=False, command="gc", retention_s=0, force=True)
    assert len(plan.dropped_stats) == 1 and any("stats cache entries" in line for line in plan.lines())
    assert {p.name for p in (root / STATS_DIR).iterdir()} == current
