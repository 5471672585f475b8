"""htdata view: the .rrd read back with Rerun's own reader holds every frame as htdata serves it.

Tests that log need rerun-sdk (the `view` extra) and skip without it; the line a missing
rerun-sdk gives is tested either way.
"""

from __future__ import annotations

import importlib.util
import sys
from collections import defaultdict

import numpy as np
import pytest

import htdata
import tests.factories as factories
from htdata.cli import main as cli_main
from htdata.errors import DatasetError
from htdata.format.tactilecodec import encode_exr
from htdata.glove.canonical import PART_NAMES
from htdata.inspect import preview, view, viewlayout
from htdata.store.episodeids import NoSuchEpisode
from tests.factories import (
    COLOURS,
    MIXED_HANDS_EPISODES,
    commit_split,
    ingest_cli,
    ingest_rawglove,
    mixed_hands_coverages,
    ot_clip,
    small_pipeline,
    write_synthetic_dataset,
)

needs_rerun = pytest.mark.skipif(importlib.util.find_spec("rerun") is None,
                                 reason="rerun-sdk is not installed (pip install '.[view]')")
BEND_DIMS = 4


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    """ep_a right 5 frames, ep_b both hands 4 frames, ep_c left 1 frame; partial coverages, bend values,
    3 samples per shard (episodes span shards)."""
    return write_synthetic_dataset(tmp_path_factory.mktemp("view") / "ds", MIXED_HANDS_EPISODES,
                                   coverages=mixed_hands_coverages(), bend_dims=BEND_DIMS, samples_per_shard=3)


def read_rrd(path) -> tuple[dict, dict]:
    """Rerun's own reader: ({entity: [row dicts sorted by frame]}, {entity: {component: pyarrow value}})."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    temporal, static = defaultdict(list), defaultdict(dict)
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        cols = {n: batch.column(n) for n in batch.schema.names if n != "rerun.controls.RowId"}
        if chunk.is_static:
            static[chunk.entity_path].update({n: c[0] for n, c in cols.items()})
            continue
        assert set(chunk.timeline_names) == {"frame", "time"}, chunk.timeline_names
        frames = cols.pop("frame").to_numpy()
        times = cols.pop("time").cast(pa.int64()).to_numpy()
        for k in range(batch.num_rows):
            row = {"frame": int(frames[k]), "time": int(times[k])}
            row.update({n: c[k] for n, c in cols.items() if c[k].is_valid})
            temporal[chunk.entity_path].append(row)
    for rows in temporal.values():
        rows.sort(key=lambda r: r["frame"])
    return dict(temporal), dict(static)


def blob(value) -> bytes:
    """The bytes of a blob component's one instance (an encoded image, an image buffer)."""
    return np.asarray(value.values[0].values, np.uint8).tobytes()


def scalars(value) -> np.ndarray:
    return np.asarray(value.values, np.float64)


def tensor(value) -> np.ndarray:
    """A Tensor:data instance as numpy, in the dtype it was logged in."""
    data = value.values[0]
    shape = data["shape"].as_py()
    return data["buffer"].value.values.to_numpy(zero_copy_only=False).reshape(shape)


def save(ds, tmp_path, **kw):
    out = tmp_path / "ep.rrd"
    result = view.view_episode(ds, save=out, **kw)
    assert result.target == str(out) and out.is_file() and not list(tmp_path.glob("*.tmp"))
    return result, *read_rrd(out)


@needs_rerun
def test_every_frame_of_both_hands_is_logged_as_htdata_serves_it(ds, tmp_path):
    result, rows, static = save(ds, tmp_path, episode="ep_b", contrast="fixed")
    plan = result.plan
    assert plan.episode_id == "ep_b" and plan.hands == ("left", "right") and plan.rgb and result.frames == 4
    assert set(rows) == {"/rgb", *(f"/{kind}/{h}" for kind in ("regions", "bend", "skew") for h in ("left", "right")),
                         "/tactile/left/map", "/tactile/right/map"}
    assert {"/episode", "/tactile/left/no_sensor", "/tactile/right/no_sensor"} <= set(static)
    reader = htdata.open(ds)
    first, n = reader.episode_range("ep_b")
    served = [reader.decoded(first + f) for f in range(n)]
    t0 = served[0]["meta"]["t_rgb_ns"]
    for entity, entity_rows in rows.items():   # one row per sample, on both timelines
        assert [r["frame"] for r in entity_rows] == list(range(n)), entity
        assert [r["time"] for r in entity_rows] == [s["meta"]["t_rgb_ns"] - t0 for s in served], entity
    for f, s in enumerate(served):
        assert blob(rows["/rgb"][f]["EncodedImage:blob"]) == reader.sample(first + f)["rgb.jpg"]   # the stored JPEG
        for hand in ("left", "right"):
            logged = np.frombuffer(blob(rows[f"/tactile/{hand}/map"][f]["DepthImage:buffer"]), np.float32)
            assert np.array_equal(logged.reshape(224, 224), s["tactile"][hand])     # float32: exact
            np.testing.assert_array_equal(scalars(rows[f"/bend/{hand}"][f]["Scalars:scalars"]), s["bend"][hand])
            assert scalars(rows[f"/skew/{hand}"][f]["Scalars:scalars"]).tolist() == [
                s["meta"]["sync_offset_ns"][hand] / 1e6]
    # region curves: the mean of each covered part of the map, parts named thumb .. palm
    cov = reader.coverage("glove_l")
    parts = reader.region_map
    names = static["/regions/left"]["SeriesLines:names"].values.to_pylist()
    assert names == [PART_NAMES[p] for p in PART_NAMES if ((parts == p) & (cov > 0)).any()] and names
    for f, s in enumerate(served):
        want = [s["tactile"]["left"][(parts == p) & (cov > 0)].mean() for p in PART_NAMES
                if ((parts == p) & (cov > 0)).any()]
        np.testing.assert_allclose(scalars(rows["/regions/left"][f]["Scalars:scalars"]), want, rtol=1e-6)
    depth, overlay = static["/tactile/left/map"], static["/tactile/left/no_sensor"]
    assert depth["DepthImage:depth_range"].values[0].as_py() == [0.0, 1.0]      # --contrast fixed: 0..1
    assert overlay["Image:draw_order"].values[0].as_py() > depth["DepthImage:draw_order"].values[0].as_py()


@needs_rerun
def test_default_episode_is_the_first_and_a_missing_hand_is_absent(ds, tmp_path):
    result, rows, static = save(ds, tmp_path)
    assert result.plan.episode_id == "ep_a" and result.plan.hands == ("right",)
    assert not [e for e in (*rows, *static) if "left" in e]          # no left entity at all, not a black one
    assert len(rows["/tactile/right/map"]) == 5
    import rerun.blueprint as rrb

    origins = [v.origin for v in _views(viewlayout.blueprint(rrb, result.plan).root_container)]
    assert origins[:2] == ["rgb", "tactile/right"] and not [o for o in origins if "left" in o]


def _views(container):
    for item in container.contents:
        yield from (_views(item) if hasattr(item, "contents") and hasattr(item, "row_shares") else [item])


@needs_rerun
def test_single_frame_episode(ds, tmp_path):
    _, rows, _ = save(ds, tmp_path, episode="ep_c")
    assert [r["frame"] for r in rows["/tactile/left/map"]] == [0] and rows["/tactile/left/map"][0]["time"] == 0


@needs_rerun
def test_glove_only_raw_count_dataset_has_no_rgb_and_logs_the_raw_grid(tmp_path):
    dataset = ingest_rawglove(tmp_path, clips=1)
    result, rows, static = save(dataset, tmp_path)
    plan = result.plan
    assert not plan.rgb and plan.raw_hands == ("left", "right")
    assert "/rgb" not in rows and "/rgb" not in static and not [e for e in rows if e.startswith("/skew")]
    import rerun.blueprint as rrb

    assert "rgb" not in [v.origin for v in _views(viewlayout.blueprint(rrb, plan).root_container)]
    reader = htdata.open(dataset)
    first, n = reader.episode_range(0)
    assert len(rows["/tactile/left/map"]) == len(rows["/raw/left"]) == n
    for f in (0, n // 2, n - 1):
        s = reader.decoded(first + f)
        for hand in ("left", "right"):
            grid = tensor(rows[f"/raw/{hand}"][f]["Tensor:data"])
            want = s["raw"][hand][s["meta"]["raw_paired"][hand]]
            assert grid.dtype == want.dtype and np.array_equal(grid, want, equal_nan=True)   # as recorded
    top = reader.layout(plan.episode["layouts"]["left"])["value"]["max"]
    assert static["/raw/left"]["Tensor:value_range"].values[0].as_py() == [0.0, float(top)]


@needs_rerun
def test_rgb_only_frames_clear_the_map_and_break_the_curves(tmp_path):
    p = np.random.default_rng(0).uniform(1000, 3072, size=(10, 16, 16)).astype(np.float32)
    p[[2, 7], 5, 9] = np.nan       # a live taxel: frames 2 and 7 are kept as RGB-only samples
    raw = tmp_path / "raw"
    factories.write_opentouch_scene(raw / "s.hdf5", [ot_clip("demo_01", 10, COLOURS[0], pressure=p)])
    factories.write_opentouch_annotations(raw / "annotations.csv", [{"id": "s::demo_01", "action": "pour"}])
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", small_pipeline(tmp_path, "opentouch"), raw, out) == 0
    _, rows, _ = save(out, tmp_path)
    maps = rows["/tactile/right/map"]
    assert [r["frame"] for r in maps if "DepthImage:buffer" in r] == [0, 1, 3, 4, 5, 6, 8, 9]
    assert [r["frame"] for r in maps if "DepthImage:buffer" not in r] == [2, 7]     # Clear rows
    regions = {r["frame"]: scalars(r["Scalars:scalars"]) for r in rows["/regions/right"]}
    assert np.isnan(regions[2]).all() and np.isfinite(regions[3]).all()
    assert len(rows["/rgb"]) == 10


@needs_rerun
def test_typo_gets_the_did_you_mean_line_and_split_parts_choose(ds, tmp_path, capsys):
    with pytest.raises(NoSuchEpisode, match=r"no episode matches 'ep_bb' \(3 episodes\); did you mean: ep_b"):
        view.view_episode(ds, episode="ep_bb", save=tmp_path / "x.rrd")
    assert cli_main(["view", str(ds), "--episode", "ep_bb", "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean: ep_b" in err and not (tmp_path / "x.rrd").exists()
    split_ds = write_synthetic_dataset(tmp_path / "split", MIXED_HANDS_EPISODES, coverages=mixed_hands_coverages())
    commit_split(split_ds, "main", {"train": ["ep_a", "ep_c"], "test": ["ep_b"]})
    result, _, _ = save(split_ds, tmp_path, split="main", part="test")
    assert result.plan.episode_id == "ep_b"
    with pytest.raises(NoSuchEpisode, match=r"'ep_a' \(1 episodes in main/test\)"):
        view.view_episode(split_ds, episode="ep_a", split="main", part="test", save=tmp_path / "y.rrd")
    assert view.view_episode(split_ds, version=1, save=tmp_path / "v1.rrd").plan.version == 1


@needs_rerun
def test_a_damaged_map_is_one_line_naming_the_sample_and_leaves_no_file(tmp_path, monkeypatch):
    made = factories.synthetic_members

    def nan_at_frame_2(spec, frame, *args, **kwargs):
        members = made(spec, frame, *args, **kwargs)
        if frame == 2:
            bad = np.zeros((224, 224), np.float32)
            bad[5, 7] = np.nan
            members["tactile_right.exr"] = encode_exr(bad)
        return members

    monkeypatch.setattr(factories, "synthetic_members", nan_at_frame_2)
    damaged = write_synthetic_dataset(tmp_path / "bad", MIXED_HANDS_EPISODES[:1])
    out = tmp_path / "out" / "ep.rrd"
    out.parent.mkdir()
    with pytest.raises(DatasetError, match="ep_a__000002"):
        view.view_episode(damaged, contrast="fixed", save=out)
    assert not list(out.parent.iterdir())        # neither the .rrd nor its .tmp


def test_without_rerun_one_line_names_the_extra(ds, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)        # import rerun -> ImportError
    with pytest.raises(view.ViewerMissing, match=r"pip install '\.\[view\]'"):
        view.load_rerun()
    assert cli_main(["view", str(ds), "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install '.[view]'" in err and not (tmp_path / "x.rrd").exists()


def test_save_must_be_an_rrd_file(ds, tmp_path, capsys):
    with pytest.raises(ValueError, match=r"\.rrd"):
        view.view_episode(ds, save=tmp_path / "x.png")
    with pytest.raises(SystemExit):
        cli_main(["view", str(ds), "--save", str(tmp_path / "x.rrd"), "--web"])
    assert "not allowed with" in capsys.readouterr().err


def test_no_sensor_overlay_shades_as_preview_does():
    cov = np.zeros((224, 224), np.uint8)
    cov[20:200, 30:190] = 1
    places = np.zeros((224, 224), np.uint8)
    places[50:100, 60:120] = 3
    tmap = np.zeros((224, 224), np.float32)
    tmap[60:70, 70:80] = 0.8
    over = viewlayout.sensor_overlay(cov, places).astype(np.float64)
    # the inferno panel under it, blended by the overlay's alpha, is the preview's panel
    panel = preview.render_tactile(tmap, np.ones_like(cov), np.zeros_like(cov, bool))[..., ::-1].astype(np.float64)
    alpha = over[..., 3:] / 255.0
    blended = over[..., :3] * alpha + panel * (1 - alpha)
    want = preview.render_tactile(tmap, cov, preview.region_outline(places))[..., ::-1].astype(np.float64)
    assert np.abs(blended - want).max() <= 1.5
    assert (over[cov > 0][:, 3] == 0).sum() > 0 and (over[cov == 0][:, 3] > 0).all()


def test_region_means_cover_only_the_parts_a_glove_covers():
    parts = np.zeros((224, 224), np.uint8)
    parts[:100] = 1
    parts[100:] = 6
    cov = np.zeros((224, 224), np.uint8)
    cov[150:] = 1
    means = viewlayout.RegionMeans.of(parts, cov)
    assert means.names == ("palm",)
    tmap = np.zeros((224, 224), np.float32)
    tmap[150:] = 0.5
    tmap[:100] = 1.0            # outside the coverage: not averaged
    assert means(tmap).tolist() == [0.5]
    assert viewlayout.RegionMeans.of(parts, np.zeros_like(cov)).names == ()


def test_episode_note_names_the_episode_and_scale(ds):
    reader = htdata.open(ds)
    plan = viewlayout.plan_episode(reader, 1, "quantile", 0.25)
    text = viewlayout.episode_text(plan)
    assert "ep_b" in text and "0..0.25" in text and "left glove_l, right glove_r" in text
