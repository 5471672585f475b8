"""The glove's own rest by default (issue 43 item 2; htdata/ingest/gloverest.py).

A raw-count knit glove (tests/factories/knitglove.py: per-taxel offsets that belong to the glove,
each recording's rest level shifted) is recorded four times; in one recording the palm is held
pressed by GRIP counts from the first frame to the last. Ingested alone, that recording's rest is
read from itself (the raw-count default) and the held grip vanishes; ingested with the glove's
other recordings, the rest comes from the glove and the grip stays pressed. The control is the
same recording ingested alone, through the same command.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from htdata.glove.restreference import MIN_RECORDINGS
from htdata.inspect.stats import episode_stats
from htdata.read.reader import DatasetReader
from htdata.store.manifest import load_manifest
from tests.factories import ingest_cli
from tests.factories.knitglove import draft_layout, knit_counts, write_glove_only

GRIP = 80.0                       # counts: a firm grip on a glove whose presses reach +150..+400
LAYOUT = "knit_right_16x16"
# 32 of the layout's 144 live cells: a grip presses a minority of a glove (the common-mode shift is a median)
HELD = (slice(None), slice(8, 12), slice(0, 8))


def _recordings(root: Path, seeds: list[int], held: int | None = None) -> Path:
    for s in seeds:
        counts = knit_counts(seed=s, rest_shift=3.0 * s)
        if s == held:
            counts[HELD] += GRIP                       # part of the palm, pressed through the whole recording
        write_glove_only(root / f"rec_{s}", LAYOUT, counts)
    return root


def _layouts(tmp_path: Path) -> Path:
    d = tmp_path / "gloves"
    d.mkdir(exist_ok=True)
    (d / f"{LAYOUT}.json").write_text(json.dumps(draft_layout(LAYOUT)))
    return d


def _contact(out: Path) -> dict[str, float]:
    with DatasetReader(out) as reader:
        per_episode, _ = episode_stats(reader, cache_dir=None)
        return {rec["episode_id"]: st["hands"]["right"]["contact_frames"] / st["hands"]["right"]["frames"]
                for rec, st in zip(reader.episodes, per_episode)}


def _report(out: Path) -> dict:
    return json.loads((out / "reports" / "ingest.json").read_text())


def _calibrations(out: Path) -> dict:
    return load_manifest(out)["calibrations"]


def test_a_grip_held_through_a_recording_stays_pressed_when_the_glove_s_recordings_are_ingested_together(tmp_path):
    layouts = _layouts(tmp_path)
    together = _recordings(tmp_path / "together", [0, 1, 2, 3], held=3)
    alone = _recordings(tmp_path / "alone", [3], held=3)
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", together, tmp_path / "ds") == 0
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", alone, tmp_path / "ds1") == 0
    held_together = _contact(tmp_path / "ds")["nat-rec_3"]
    held_alone = _contact(tmp_path / "ds1")["nat-rec_3"]
    # presses come and go (half the frames); the held grip adds contact in every other frame
    assert held_together > 0.95, held_together
    assert held_alone < 0.75, held_alone
    notes = " ".join(_report(tmp_path / "ds")["notes"])
    assert "pooled over 4 recordings" in notes and LAYOUT in notes
    # the report times the pooling (the driver bench takes it out of the driver's growth: bounded by POOL_MAX)
    timing = _report(tmp_path / "ds")["timing"]
    assert (timing["rest_recordings"], timing["rest_gloves"]) == (4, 1) and 0 < timing["rest_s"] <= timing["plan_s"]
    assert _report(tmp_path / "ds1")["timing"]["rest_recordings"] == 0
    assert {c["baseline"] for c in _calibrations(tmp_path / "ds").values()} == {"shift"}
    assert {c["baseline"] for c in _calibrations(tmp_path / "ds1").values()} == {"drift"}   # one recording alone


def test_fewer_recordings_than_the_pool_needs_keep_the_per_recording_default(tmp_path):
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", list(range(MIN_RECORDINGS - 1)))
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, tmp_path / "ds") == 0
    assert {c["baseline"] for c in _calibrations(tmp_path / "ds").values()} == {"drift"}
    notes = " ".join(_report(tmp_path / "ds")["notes"])
    assert "pooled over" not in notes and "fewer than 3 of the glove's recordings" in notes


def test_an_append_reuses_the_dataset_s_glove_rest_and_keeps_committed_episodes(tmp_path):
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", [0, 1, 2])
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, out) == 0
    before = _calibrations(out)
    _recordings(raw, [4], held=4)                        # a new session, its grip held throughout
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, out) == 0
    report = _report(out)
    after = _calibrations(out)
    assert set(before) <= set(after)                     # the committed episodes' calibration is kept
    assert {c["taxel_calibration_sha256"] for c in after.values()} == \
        {c["taxel_calibration_sha256"] for c in before.values()}   # one reference for old and new episodes
    assert "reused from the dataset" in " ".join(report["notes"])
    assert _contact(out)["nat-rec_4"] > 0.95


def test_the_pooled_reference_is_the_median_of_each_recording_s_rest(tmp_path):
    """The file the ingest normalised with is the glove's rest, not any one recording's: compare it with the
    rest each recording shows on its own (10th percentile), which the held recording's palm does not share."""
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", [0, 1, 2], held=2)
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, out) == 0
    ref_file, = (out / ".work").glob(f"glove-rest-{LAYOUT}-*.npz")
    ref = np.load(ref_file)["offset"]
    own = []
    for s in (0, 1, 2):
        counts = knit_counts(seed=s, rest_shift=3.0 * s)
        counts[HELD] += GRIP if s == 2 else 0.0
        own.append(np.percentile(counts, 10, axis=0))
    assert np.allclose(ref, np.median(np.stack(own), axis=0), atol=0.51)   # float16 counts: half-count steps
    assert np.median(own[2][8:12, 0:8] - ref[8:12, 0:8]) > GRIP - 10   # the held grip is not the glove's rest


def test_renormalise_gives_a_dataset_the_glove_s_rest_from_its_stored_rows(tmp_path, capsys):
    """Three recordings appended one at a time each got the per-recording default (one recording alone);
    `htdata renormalise` with the same pipeline pools the glove's rest over the raw rows the dataset stores
    (the recordings may be archived by then), after a dry run that writes nothing; a second run changes nothing."""
    from htdata.cli import main as cli_main
    layouts = _layouts(tmp_path)
    out = tmp_path / "ds"
    for s in (0, 1, 2):
        _recordings(tmp_path / f"session_{s}", [s], held=2)
        assert ingest_cli("--layouts", layouts, "--pipeline", "native", tmp_path / f"session_{s}", out) == 0
    assert {c["baseline"] for c in _calibrations(out).values()} == {"drift"}
    assert _contact(out)["nat-rec_2"] < 0.75
    capsys.readouterr()
    assert cli_main(["renormalise", str(out), "--pipeline", "native", "--dry-run"]) == 0
    text = capsys.readouterr()
    assert "pooled over 3 episodes of the dataset" in text.err and "would renormalise" in text.out
    assert not list((out / ".work").glob("glove-rest-*"))          # a dry run writes nothing into the dataset
    assert cli_main(["renormalise", str(out), "--pipeline", "native"]) == 0
    assert {c["baseline"] for c in _calibrations(out).values()} >= {"shift"}
    assert _contact(out)["nat-rec_2"] > 0.95
    capsys.readouterr()
    assert cli_main(["renormalise", str(out), "--pipeline", "native"]) == 0
    text = capsys.readouterr()
    assert "reused from the dataset" in text.err and "nothing changed" in text.out


def test_an_append_never_changes_how_committed_episodes_were_normalised(tmp_path):
    """Two recordings (too few to pool) then a third in the same folder: the append ingests only the new one,
    with the per-recording default the committed ones have (renormalise pools them: test above)."""
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", [0, 1])
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, out) == 0
    _recordings(raw, [2])
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, out) == 0
    report = _report(out)
    assert (report["units_run"], report["episodes_unchanged"]) == (1, 2), report
    assert {c["baseline"] for c in _calibrations(out).values()} == {"drift"}


def test_a_pipeline_with_its_own_table_keeps_it_beside_one_that_pools(tmp_path):
    """Two sources of one glove in one ingest: the pipeline that sets [normalise.<layout>] keeps its table; the
    one that leaves the glove to the default gets the pooled rest; the note names only that one."""
    layouts = _layouts(tmp_path)
    pooled = _recordings(tmp_path / "pooled", [0, 1, 2])
    tabled = _recordings(tmp_path / "tabled", [3, 4, 5])
    toml = (Path(__file__).parents[2] / "pipelines" / "native.toml").read_text().replace(
        'name = "native"', 'name = "native_tabled"', 1)
    toml += f'\n[normalise.{LAYOUT}]\nbaseline = "percentile"\nnoise_k = 5\n'
    (tmp_path / "tabled.toml").write_text(toml)
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", layouts, "--pipeline", f"native={pooled}",
                      "--pipeline", f"{tmp_path / 'tabled.toml'}={tabled}", out) == 0
    baselines = sorted(c["baseline"] for c in _calibrations(out).values())
    assert baselines == ["percentile", "shift"], baselines
    note, = [n for n in _report(out)["notes"] if "glove's own" in n]
    assert "'native'" in note and "native_tabled" not in note


def test_an_append_to_a_moved_dataset_reuses_its_episodes(tmp_path):
    """The pooled rest's file lives in the dataset's work folder, which moves with it: its path is no part of
    an episode's input fingerprint, so an append after a move ingests only the new recording."""
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", [0, 1, 2])
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, tmp_path / "ds") == 0
    moved = tmp_path / "elsewhere" / "ds"
    moved.parent.mkdir()
    (tmp_path / "ds").rename(moved)
    _recordings(raw, [3])
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, moved) == 0
    report = _report(moved)
    assert (report["units_run"], report["episodes_unchanged"]) == (1, 3), report


def test_a_recording_that_cannot_be_read_fails_alone_and_the_others_still_pool(tmp_path):
    """Pooling reads recordings before the units run: a damaged one is left out of the pool, and its own unit
    fails it by name, as an ingest without pooling would."""
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", [0, 1, 2, 3], held=3)
    damaged, = (raw / "rec_1").glob("*.npz")
    damaged.write_bytes(damaged.read_bytes()[:200])
    out = tmp_path / "ds"
    assert ingest_cli("--layouts", layouts, "--pipeline", "native", raw, out) == 1     # an episode failed
    report = _report(out)
    assert [f["episode_id"] for f in report["failures"]] == ["nat-rec_1"], report["failures"]
    assert "pooled over 3 recordings" in " ".join(report["notes"])
    assert _contact(out)["nat-rec_3"] > 0.95


def test_pooling_reads_a_bounded_number_of_rows_of_a_long_recording(tmp_path, monkeypatch):
    """A rest is a low percentile: pooling reads at most REST_BYTES of a recording's rows, evenly spaced, so a
    long (or hostile) recording costs bounded memory in the driver."""
    from htdata.ingest import gloverest
    seen = []
    real = gloverest.recording_rest
    monkeypatch.setattr(gloverest, "REST_BYTES", 4 * 16 * 16 * 50)             # 50 rows of a 16x16 glove
    monkeypatch.setattr(gloverest, "recording_rest", lambda rows, conv: seen.append(len(rows)) or real(rows, conv))
    layouts = _layouts(tmp_path)
    raw = _recordings(tmp_path / "raw", [0, 1, 2])
    assert ingest_cli("--layouts", layouts, "--workers", "0", "--pipeline", "native", raw, tmp_path / "ds") == 0
    assert seen == [50, 50, 50]                                                 # of 240 rows each
