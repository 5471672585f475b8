"""Raw glove rows kept exactly (format 3), calibrations recorded, noise floor, `htdata renormalise`."""

from __future__ import annotations

import io
import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from htdata.cli import main as cli
from htdata.errors import ArgumentError
from htdata.format.table import INDEX_FILE, LEGACY_INDEX_DTYPE, MANIFEST_FILE, raw_member, tactile_member
from htdata.glove.calibration import calibration_id, episode_normaliser
from htdata.glove.layouts import load_layout
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.read.itemoptions import ItemOptions
from htdata.read.reader import DatasetReader
from htdata.store.manifest import load_episodes, load_index, load_manifest
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from tests.factories import COLOURS, PERIOD, ingest_cli, make_opentouch, small_pipeline
from tests.factories.legacy import as_format3, reseal_records

LAYOUT = "opentouch_right_16x16"


def counts_recording(folder: Path, frames: int = 12, nan_row: int | None = None, dup_row: int | None = None,
                     dtype=np.uint16, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A native recording: 30 Hz video, 100 Hz glove of integer raw counts; returns (values, timestamps)."""
    t_video = np.arange(frames, dtype=np.int64) * PERIOD
    t_glove = np.arange(0, frames * PERIOD, 10_000_000, dtype=np.int64)
    rng = np.random.default_rng(seed)
    values = rng.integers(0, 3072, size=(t_glove.size, 16, 16)).astype(dtype)
    if dup_row is not None:
        t_glove[dup_row + 1] = t_glove[dup_row]
    rec = NativeRecording(task="grasp", scene="lab", video_storage="jpeg",
                          video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * frames,
                          video_timestamps_ns=t_video,
                          hands={"right": NativeHand(LAYOUT, values.astype(np.float32), t_glove)})
    write_native_recording(folder, rec)
    stored = values
    if nan_row is not None:   # float source with one NaN row: the frame paired with it is dropped
        stored = values.astype(np.float32)
        stored[nan_row, :, 8:] = np.nan
    np.savez(folder / "tactile_right.npz", values=stored, timestamps_ns=t_glove)   # source dtype as given
    return stored, t_glove


def stored_rows(root: Path, episode: str, hand: str = "right") -> tuple[dict[int, np.ndarray], dict[int, int], list]:
    """Union over an episode's samples: source row -> raw row, source row -> timestamp; and per-sample arrays."""
    reader = DatasetReader(root)
    first, n = reader.episode_range(episode)
    rows, times, arrays = {}, {}, []
    for i in range(first, first + n):
        s = reader.decoded(i)
        if hand not in s["raw"]:      # an RGB-only sample (its frame's tactile was dropped) holds no rows
            assert s["meta"].get("rgb_only")
            continue
        arr, meta = s["raw"][hand], s["meta"]
        arrays.append(arr)
        assert arr.shape[0] == len(meta["raw_row"][hand]) == len(meta["raw_t_ns"][hand])
        assert meta["raw_row"][hand][meta["raw_paired"][hand]] >= 0
        assert meta["raw_t_ns"][hand] == sorted(meta["raw_t_ns"][hand])
        for r, t, v in zip(meta["raw_row"][hand], meta["raw_t_ns"][hand], arr):
            rows[r], times[r] = v, t
    return rows, times, arrays


@pytest.fixture
def native_counts(tmp_path):
    src = tmp_path / "raw"
    values, ts = counts_recording(src / "rec_counts")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp_path, 'native')}={src}", "--set", "tactile.maps=stored",
                      out) == 0
    return out, values, ts


def test_every_glove_row_is_stored_bit_for_bit_in_the_source_dtype(native_counts):
    out, values, ts = native_counts
    episode = load_episodes(out)[0]["episode_id"]
    rows, times, arrays = stored_rows(out, episode)
    assert sorted(rows) == list(range(values.shape[0]))          # 100 Hz glove: nothing lost (~3 rows per frame)
    assert all(a.dtype == np.uint16 for a in arrays)
    for r, v in rows.items():
        assert v.dtype == values.dtype and v.tobytes() == values[r].tobytes()
        assert times[r] == ts[r]
    assert sum(a.shape[0] for a in arrays) == values.shape[0]    # each row once (no row paired twice here)


def test_paired_row_is_the_one_the_map_was_made_from(native_counts):
    out, _, _ = native_counts
    reader, manifest = DatasetReader(out), load_manifest(out)
    episode = load_episodes(out)[0]
    layout = load_layout(out / manifest["layouts"][LAYOUT]["file"])
    normaliser = episode_normaliser(manifest, episode, "right", layout)
    from htdata.glove.rasterise import Rasteriser
    raster = Rasteriser(layout)
    for i in range(len(reader)):
        s = reader.decoded(i)
        k = s["meta"]["raw_paired"]["right"]
        # the raw-count default (drift) reads its rest at the row's place in the episode
        values, _ = normaliser.apply(s["raw"]["right"][k][None], rows=[s["meta"]["raw_row"]["right"][k]])
        expect = raster.render(values)[0]
        assert np.abs(expect - s["tactile"]["right"]).max() <= 2.5e-4    # the map codec's rounding only


def test_manifest_records_the_calibration(native_counts):
    out, _, _ = native_counts
    manifest, episode = load_manifest(out), load_episodes(out)[0]
    cal_id = episode["calibration"]["right"]
    entry = manifest["calibrations"][cal_id]
    assert entry["layout"] == LAYOUT and entry["convention"] == "inverted" and entry["max_value"] == 3072
    assert entry["revision"] == 1 and "value block" in entry["from"]
    # an inverted raw-count glove without a [normalise] table: the raw-count default (issue 43)
    assert entry["baseline"] == "drift" and entry["noise_k"] == 5
    assert cal_id == calibration_id(LAYOUT, NormaliseConfig.from_layout_value(load_layout(LAYOUT).value))


def test_rows_of_dropped_frames_and_duplicate_timestamps_are_kept(tmp_path):
    src = tmp_path / "raw"
    values, ts = counts_recording(src / "rec_nan", nan_row=10, dup_row=20)   # row 10 = frame 3's
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp_path, 'native')}={src}", out) == 0
    episode = load_episodes(out)[0]
    assert episode["dropped_frames"].get("nonfinite_tactile:right", 0) == 1
    rows, times, _ = stored_rows(out, episode["episode_id"])
    assert sorted(rows) == list(range(values.shape[0]))
    assert np.isnan(rows[10][:, 8:]).all() and not np.isnan(rows[10][:, :8]).any()   # stored as read
    assert rows[21].tobytes() == values[21].tobytes() and times[21] == times[20]


def test_keep_raw_false_stores_no_raw_and_maps_are_unchanged(tmp_path, native_counts):
    out, _, _ = native_counts
    pipeline = small_pipeline(tmp_path, "native")
    pipeline.write_text(pipeline.read_text().replace("keep_bend = true", "keep_bend = true\nkeep_raw = false\n"
                                                                         "maps = \"stored\""))
    out2 = tmp_path / "ds_noraw"
    assert ingest_cli("--pipeline", f"{pipeline}={tmp_path / 'raw'}", out2) == 0
    a, b = DatasetReader(out), DatasetReader(out2)
    assert len(a) == len(b)
    for i in range(len(a)):
        x, y = a.sample(i), b.sample(i)
        assert raw_member("right") in x and raw_member("right") not in y
        assert x[tactile_member("right")] == y[tactile_member("right")]


def test_renormalise_with_the_original_calibration_is_byte_identical(tmp_path, native_counts):
    out, _, _ = native_counts
    assert cli(["renormalise", str(out), "--pipeline", "native", "--force"]) == 0
    a, b = DatasetReader(out, version=1), DatasetReader(out, version=2)
    assert load_manifest(out)["version"] == 2 and len(a) == len(b)
    for i in range(len(a)):
        assert a.sample(i) == b.sample(i)


def test_renormalise_to_a_new_calibration_and_back(tmp_path, native_counts, capsys):
    out, _, _ = native_counts
    setting = ["--set", f"normalise.{LAYOUT}.baseline=rest_window", "--set", f"normalise.{LAYOUT}.noise_k=3"]
    assert cli(["renormalise", str(out), "--pipeline", "native", "--dry-run", *setting]) == 0
    assert load_manifest(out)["version"] == 1                         # dry run wrote nothing
    assert cli(["renormalise", str(out), "--pipeline", "native", *setting]) == 0
    manifest, episode = load_manifest(out), load_episodes(out)[0]
    new = manifest["calibrations"][episode["calibration"]["right"]]
    assert new["baseline"] == "rest_window" and new["noise_k"] == 3 and new["revision"] == 2
    assert new["convention"] == "inverted" and new["max_value"] == 3072     # kept from the layout's value block
    assert set(episode["calibration_fit"]["right"]) == {"baseline", "noise_floor"}
    v1, v2 = DatasetReader(out, version=1), DatasetReader(out, version=2)
    assert any(v1.sample(i)[tactile_member("right")] != v2.sample(i)[tactile_member("right")] for i in range(len(v1)))
    assert all(v1.sample(i)[raw_member("right")] == v2.sample(i)[raw_member("right")] for i in range(len(v1)))
    # back to the layout's calibration: the version-1 maps again, from the raw rows alone
    assert cli(["renormalise", str(out), "--pipeline", "native"]) == 0
    v3 = DatasetReader(out, version=3)
    assert all(v1.sample(i) == v3.sample(i) for i in range(len(v1)))
    capsys.readouterr()
    assert cli(["renormalise", str(out), "--pipeline", "native"]) == 0     # again: nothing to change, no version
    assert "nothing changed: version 3 stays current" in capsys.readouterr().out
    assert load_manifest(out)["version"] == 3
    assert cli(["validate", str(out), "--deep"]) == 0


def test_renormalise_resolves_each_layout_once(native_counts, monkeypatch):
    """`[normalise]` is resolved once per layout per run: the plan, its calibrations, the rest-level warnings
    and the rewrite read one config (they resolved it four times, issue 48)."""
    from htdata.glove.normalisesettings import NormaliseSettings

    out, _, _ = native_counts
    resolved, real = [], NormaliseSettings._resolve
    monkeypatch.setattr(NormaliseSettings, "_resolve",
                        lambda self, layout: resolved.append(layout.layout_id) or real(self, layout))
    assert cli(["renormalise", str(out), "--pipeline", "native", "--set", f"normalise.{LAYOUT}.baseline=none"]) == 0
    assert load_manifest(out)["version"] == 2 and resolved == [LAYOUT]


def test_renormalise_refuses_episodes_without_raw_rows(tmp_path, capsys):
    pipeline = small_pipeline(tmp_path, "opentouch")
    pipeline.write_text(pipeline.read_text() + "\n[tactile]\nkeep_raw = false\nmaps = \"stored\"\n"
                        if "[tactile]" not in pipeline.read_text()
                        else pipeline.read_text().replace("[tactile]", "[tactile]\nkeep_raw = false\nmaps = \"stored\""))
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", f"{pipeline}={make_opentouch(tmp_path / 'ot')}", out) == 0
    assert cli(["renormalise", str(out), "--pipeline", "opentouch", "--force"]) == 2
    err = capsys.readouterr().err
    assert "no stored raw glove rows" in err and "ot-home_kitchen_p1-demo_01" in err
    assert load_manifest(out)["version"] == 1


def test_noise_floor_silences_rest_noise_of_raw_count_gloves():
    """Raw counts ~490..1022 with per-taxel offsets and noise: a baseline alone leaves fake contact at rest."""
    layout = load_layout(LAYOUT)
    rng = np.random.default_rng(3)
    offset = rng.uniform(490, 560, size=(16, 16))
    rest = offset + rng.normal(0, 4.0, size=(40, 16, 16))
    press = rest[-1:] + 0.0
    press[0, 4:8, 4:8] += 300                                    # a real contact
    raw = np.concatenate([rest, press]).astype(np.float32)
    direct = dict(convention="direct", max_value=1023.0, baseline="rest_window", rest_frames=20)
    plain = Normaliser(NormaliseConfig(**direct), layout)
    plain.fit_baseline(raw)
    floored = Normaliser(NormaliseConfig(**direct, noise_k=3.0), layout)
    floored.fit_baseline(raw)
    live = layout.live_mask
    a, _ = plain.apply(raw[20:40])
    b, _ = floored.apply(raw[20:40])
    assert (a[:, live] > 0).mean() > 0.3                       # fake contact almost everywhere at rest
    assert (b[:, live] > 0).mean() < 0.01                      # the floor removes it
    c, _ = floored.apply(raw[40:])
    assert c[0, 4:8, 4:8][live[4:8, 4:8]].min() > 0.2          # and keeps the real contact
    fitted = floored.fitted()
    restored = Normaliser(NormaliseConfig(**direct, noise_k=3.0), layout).restore(fitted)
    assert np.array_equal(restored.apply(raw)[0], floored.apply(raw)[0], equal_nan=True)


@pytest.mark.parametrize("bad", [dict(noise_k=-1.0), dict(noise_k=2.0, baseline="none"),
                                 dict(noise_floor=1.5), dict(noise_floor=float("nan"))])
def test_noise_settings_are_checked(bad):
    with pytest.raises(ValueError, match="noise"):
        NormaliseConfig(**{"baseline": "rest_window", **bad}).validate()


def test_a_format_2_index_is_read_as_the_current_dtype(native_counts, tmp_path):
    out = as_format3(shutil.copytree(native_counts[0], tmp_path / "v3"))     # a format 2 index.npy, below
    manifest = json.loads((out / MANIFEST_FILE).read_text())
    index_path = out / manifest["index_file"]
    rows = load_index(out, mmap=False)
    legacy = np.zeros(rows.shape, dtype=LEGACY_INDEX_DTYPE)
    for name in LEGACY_INDEX_DTYPE.names:
        legacy[name] = rows[name]
    buf = io.BytesIO()
    np.save(buf, legacy)
    index_path.write_bytes(buf.getvalue())
    again = load_index(out)
    assert again.dtype == rows.dtype and not again["size_raw_right"].any()
    assert all(np.array_equal(again[n], rows[n]) for n in LEGACY_INDEX_DTYPE.names)
    assert INDEX_FILE == "index.npy"


def test_episode_stream_is_the_recording_full_rate(native_counts):
    from htdata.read.rawstream import episode_stream

    out, values, ts = native_counts
    stream = episode_stream(DatasetReader(out), 0, "right")
    assert len(stream) == values.shape[0] and stream.rows.dtype == values.dtype
    assert np.array_equal(stream.source_row, np.arange(values.shape[0]))
    assert np.array_equal(stream.t_ns, ts) and stream.rows.tobytes() == values.tobytes()
    with pytest.raises(ValueError, match="no raw left rows"):
        episode_stream(DatasetReader(out), 0, "left")


def test_loader_maps_from_raw_rows_match_the_stored_maps(native_counts):
    import torch

    from htdata.read.torchdata import TactileFrameDataset, TactileStream

    out, _, _ = native_counts
    raw, stored = TactileFrameDataset(out), TactileFrameDataset(out, options=ItemOptions(maps_from="stored"))
    assert raw._builder.serving.rendered and not stored._builder.serving.rendered   # best: nearest mode + raw rows
    diffs = [float((raw[i]["tactile"] - stored[i]["tactile"]).abs().max()) for i in range(len(raw))]
    half = json.loads((out / "dataset.json").read_text())["codec"]["tactile"]["pixel_type"] == "half"
    assert (0 < max(diffs) <= 2.5e-4) if half else max(diffs) == 0.0   # only the map codec's rounding (float: none)
    streamed = torch.stack([x["tactile"] for x in TactileStream(out)])
    assert torch.equal(streamed, torch.stack([raw[i]["tactile"] for i in range(len(raw))]))
    with pytest.raises(ValueError, match="maps_from"):
        TactileFrameDataset(out, options=ItemOptions(maps_from="exr"))


def stuck_taxel_dataset(tmp_path) -> tuple[Path, tuple[int, int]]:
    """A 40-frame native episode, no load anywhere but one taxel stuck at half scale; (dataset, its cell)."""
    layout = load_layout(LAYOUT)
    frames = 40
    t_video = np.arange(frames, dtype=np.int64) * PERIOD
    values = np.full((frames, 16, 16), 3072.0, np.float32)          # inverted units: 3072 = no load
    r, c = map(int, np.argwhere(layout.live_mask)[20])
    values[:, r, c] = 1536.0                                         # stuck at 0.5
    write_native_recording(tmp_path / "raw" / "rec_stuck", NativeRecording(
        task="grasp", scene="lab", video_storage="jpeg", video_timestamps_ns=t_video,
        video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * frames,
        hands={"right": NativeHand(LAYOUT, values, t_video)}))
    out = tmp_path / "ds"
    # baseline "none": a glove calibrated to read its rest as no load (the raw-count default's own rest, each
    # cell's 10th percentile, would take a cell stuck all episode long for its rest)
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp_path, 'native')}={tmp_path / 'raw'}",
                      "--set", f"normalise.{LAYOUT}.baseline=none", out) == 0
    return out, (r, c)


def test_episode_record_carries_taxel_health(tmp_path):
    """A taxel stuck at half scale in a 40-frame episode is named in the record; the rest is clean."""
    layout = load_layout(LAYOUT)
    out, (r, c) = stuck_taxel_dataset(tmp_path)
    health = load_episodes(out)[0]["taxel_health"]["right"]
    assert health["assessed"] and health["live"] == int(layout.live_mask.sum())
    assert health["counts"]["stuck"] == 1 and health["cells"] == {"stuck": [[r, c]]}
    assert sum(health["counts"].values()) == 1


def test_glove_rate_windows_follow_the_full_rate_stream(native_counts):
    from htdata.read.rawstream import RawMapRenderer
    from htdata.read.torchglove import GloveRateWindowDataset

    out, values, ts = native_counts
    windows = GloveRateWindowDataset(out, window=4)
    assert windows.options == ItemOptions()
    reader = DatasetReader(out)
    assert len(windows) == len(reader) - 1          # frame 0's paired row (row 0) has no 3 rows before it
    item = windows[len(windows) - 1]
    paired = json.loads(reader.sample(int(item["index"]))["json"])
    t_paired = paired["raw_t_ns"]["right"][paired["raw_paired"]["right"]]
    end = int(np.flatnonzero(ts == t_paired)[0])
    assert item["t_ns"].tolist() == ts[end - 3:end + 1].tolist()       # 10 ms apart: the glove's own rate
    assert item["tactile"].shape == (4, 1, 224, 224)
    # the last map is the paired row's, as the loader renders it; the others are rows between frames
    assert np.array_equal(item["tactile"][-1, 0].numpy(), RawMapRenderer(reader).sample_map(int(item["index"]), "right"))
    renderer = RawMapRenderer(reader)
    normaliser, raster = renderer.parts_for(0, "right")
    expect = raster.render(normaliser.apply(values[end - 3:end + 1], rows=np.arange(end - 3, end + 1))[0])
    assert np.array_equal(item["tactile"][:, 0].numpy(), expect)


def test_glove_rate_windows_take_item_options(native_counts):
    """One `options=ItemOptions` as the other torch datasets; the old keywords warn and make the same object."""
    import htdata
    from htdata.read.torchglove import GloveRateWindowDataset

    out, _, _ = native_counts
    opts = ItemOptions(hands=("right",), version=1)
    windows = GloveRateWindowDataset(out, window=2, options=opts)
    assert windows.options is opts and len(windows) == len(DatasetReader(out)) - 1
    with pytest.warns(DeprecationWarning, match=r"GloveRateWindowDataset\(hands=\('right',\), version=1\) is "
                                                r"deprecated: pass options=ItemOptions"):
        by_kw = GloveRateWindowDataset(out, window=2, hands=("right",), version=1)
    assert by_kw.options == opts and np.array_equal(by_kw.items, windows.items)
    with pytest.warns(DeprecationWarning):
        assert GloveRateWindowDataset(out, 2, None, None, ("right",)).options == ItemOptions(hands=("right",))
    with pytest.raises(ArgumentError, match="not both"):
        GloveRateWindowDataset(out, window=2, options=opts, hands=("left",))
    for refused in (dict(maps_from="stored"), dict(members=("rgb",)), dict(constants="once"), dict(on_error="skip")):
        with pytest.raises(ArgumentError):
            GloveRateWindowDataset(out, window=2, options=ItemOptions(**refused))
    with warnings.catch_warnings():
        warnings.simplefilter("error")       # the view takes the fields as keywords: not the deprecated path
        viewed = htdata.open(out).torch.glove_windows(window=2, hands=("right",))
    assert viewed.options == ItemOptions(hands=("right",), version=viewed.reader.version)
    assert np.array_equal(viewed.items, windows.items)


def test_merge_keeps_the_calibrations_of_both_datasets(tmp_path, native_counts):
    out, _, _ = native_counts
    setting = ["--set", f"normalise.{LAYOUT}.baseline=rest_window", "--set", f"normalise.{LAYOUT}.noise_k=2"]
    assert cli(["renormalise", str(out), "--pipeline", "native", *setting]) == 0
    src = tmp_path / "raw_b"
    counts_recording(src / "rec_other", seed=5)
    other = tmp_path / "ds_b"
    assert ingest_cli("--pipeline", f"{small_pipeline(tmp_path, 'native')}={src}", "--set", "tactile.maps=stored",
                      other) == 0
    merged = tmp_path / "merged"
    assert cli(["merge", str(out), str(other), str(merged)]) == 0
    manifest, episodes = load_manifest(merged), load_episodes(merged)
    used = {ep["calibration"]["right"] for ep in episodes}
    assert len(used) == 2 and used == set(manifest["calibrations"])
    assert sorted(e["revision"] for e in manifest["calibrations"].values()) == [1, 2]
    assert cli(["validate", str(merged), "--deep"]) == 0


def test_renormalise_recomputes_taxel_health_and_names_the_frame_on_bad_settings(tmp_path, capsys):
    out, _ = stuck_taxel_dataset(tmp_path)
    assert load_episodes(out)[0]["taxel_health"]["right"]["counts"]["stuck"] == 1
    # a 1e-3 scale puts the stuck taxel at 5e-4, below the stuck level: the record's health follows the maps
    assert cli(["renormalise", str(out), "--pipeline", "native", "--set", f"normalise.{LAYOUT}.baseline=none",
                "--set", f"normalise.{LAYOUT}.scale=0.001"]) == 0
    health = load_episodes(out)[0]["taxel_health"]["right"]
    assert health["assessed"] and sum(health["counts"].values()) == 0
    # clip = false with a scale pushing the stuck taxel above 1: refused, naming episode, frame and hand
    assert cli(["renormalise", str(out), "--pipeline", "native", "--set", f"normalise.{LAYOUT}.baseline=none",
                "--set", f"normalise.{LAYOUT}.scale=50", "--set", f"normalise.{LAYOUT}.clip=false"]) == 2
    err = capsys.readouterr().err
    assert "nat-rec_stuck frame 0 right hand" in err and "clip=false" in err
    assert load_manifest(out)["version"] == 2                      # nothing written
    assert cli(["validate", str(out)]) == 0 and not list((out / "shards").glob("*.tmp"))


def test_validate_checks_the_maps_the_loaders_serve(native_counts):
    """Loaders render maps from raw rows (the default); validate fails when those differ from the stored maps."""
    from htdata.read.rawstream import MapServing
    from htdata.validate import validate_dataset
    from tests.factories import rewrite_manifest

    root = native_counts[0]
    manifest = load_manifest(root)
    assert MapServing.choose(manifest).rendered
    ok = validate_dataset(root, deep=True)
    assert ok["ok"] and ok["checks"]["content"]["checked"]["served_maps"] > 0
    for cal in manifest["calibrations"].values():     # a calibration record that no longer fits the maps
        cal["max_value"] = float(cal["max_value"]) * 2
    rewrite_manifest(root, manifest)
    bad = validate_dataset(root, deep=True)            # its id no longer hashes its content: refused first
    assert [f["what"] for f in bad["checks"]["structure"]["failures"]] == ["calibration_record"]
    # the same edit under a consistent id (episodes re-pointed, sha256 re-sealed): the stored-vs-rendered
    # cross-check is what catches it
    (old, cal), = manifest["calibrations"].items()
    new = calibration_id(cal["layout"], NormaliseConfig(**{k: v for k, v in cal.items()
                                                          if k in NormaliseConfig.__dataclass_fields__}))
    manifest["calibrations"] = {new: cal}
    rewrite_manifest(root, manifest)

    def repoint(records):
        for record in records:
            record["calibration"] = {h: new if c == old else c for h, c in record["calibration"].items()}

    reseal_records(root, repoint)
    bad = validate_dataset(root, deep=True)
    content = bad["checks"]["content"]
    assert not bad["ok"] and content["failure_counts"].get("served_map", 0) > 0
    assert content["failure_counts"].get("taxels_sha256", 0) == 1          # and the ingest's taxel digest
    assert any("calibration record and the stored maps disagree" in f["message"] for f in content["failures"])
