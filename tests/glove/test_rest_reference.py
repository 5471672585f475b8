"""The glove's own rest (htdata/glove/restreference.py) and baseline = "shift" (htdata/glove/baselinefit.py).

A grip held through a whole recording sits above rest from its first frame to its last: a rest read from the
recording itself (the raw-count default, each cell's low percentile) takes it for rest. The glove's rest,
pooled over its other recordings, plus the recording's common-mode shift, keeps it pressed (issue 43).
"""

from __future__ import annotations

import dataclasses
import hashlib
import subprocess
import sys

import numpy as np
import pytest

from htdata.errors import ArgumentError, ConfigError
from htdata.glove.layouts import load_layout
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.glove.restreference import pooled_reference, recording_rest, write_rest_reference

GRID = (4, 8)


def _recordings(n=4, frames=300, held=(1, 2), convention="direct", seed=0):
    """`n` recordings of a 4x8 glove: per-cell offsets ~550, noise 1 count, a slow common-mode wander;
    the last one reads 20 counts higher everywhere and holds cell `held` 40 counts above its rest throughout."""
    rng = np.random.default_rng(seed)
    offsets = 550 + rng.uniform(-30, 30, GRID)
    out = []
    for k in range(n):
        x = offsets + rng.normal(0, 1.0, (frames, *GRID)) + np.linspace(0, 3, frames)[:, None, None]
        if k == n - 1:
            x += 20.0
            x[:, held[0], held[1]] += 40.0
        out.append(np.round(1023 - x if convention == "inverted" else x).astype(np.float32))
    return out, offsets


@dataclasses.dataclass
class _Layout:
    live_mask: np.ndarray
    layout_id: str = "test_glove"
    value: dict = dataclasses.field(default_factory=lambda: {"convention": "direct", "max": 1023, "step": 1})


def _values(rows, cfg, layout):
    norm = Normaliser(cfg, layout)
    norm.fit_episode(rows, 30.0, np.arange(len(rows)))
    return norm.apply(rows, rows=np.arange(len(rows)))[0]


@pytest.mark.parametrize("convention", ["direct", "inverted"])
def test_a_grip_held_through_a_recording_stays_pressed_on_the_glove_s_rest(tmp_path, convention):
    recs, offsets = _recordings(convention=convention)
    layout = _Layout(np.ones(GRID, bool), value={"convention": convention, "max": 1023, "step": 1})
    default = NormaliseConfig.from_layout_value(layout.value)
    held = _values(recs[-1], default, layout)
    assert (held[:, 1, 2] > 0).mean() < 0.2           # the clip's own rest: the grip taken for rest
    ref = pooled_reference([recording_rest(r, convention) for r in recs[:-1]])
    expect = offsets - 1.28 if convention == "direct" else 1023 - offsets + 1.28   # the 10th pct. toward no press
    assert np.abs(ref - expect).max() < 2.5               # + rounding and the 3-count wander
    path = tmp_path / "rest.npz"
    write_rest_reference(path, ref)
    shift = dataclasses.replace(default, baseline="shift", taxel_calibration=str(path),
                                taxel_calibration_sha256=hashlib.sha256(path.read_bytes()).hexdigest()).validate()
    values = _values(recs[-1], shift, layout)
    assert (values[:, 1, 2] > 0).mean() > 0.99        # held through: pressed in every frame
    others = np.ones(GRID, bool)
    others[1, 2] = False
    assert (values[:, others] > 0).mean() < 0.01      # +20 counts common mode and the wander: still rest
    assert ((values[:, 1, 2] > 28 / 1023) & (values[:, 1, 2] < 44 / 1023)).all()   # 40 counts less the noise floor


def test_the_reference_is_the_median_over_recordings_so_one_held_grip_does_not_move_it():
    recs, _ = _recordings(n=3)
    rests = [recording_rest(r, "direct") for r in recs]
    ref = pooled_reference(rests)
    assert abs(ref[1, 2] - np.median([r[1, 2] for r in rests])) < 1e-4 and rests[-1][1, 2] - ref[1, 2] > 50
    with_nan = [r.copy() for r in rests]
    for r in with_nan:
        r[0, 0] = np.nan                              # a cell no recording saw: the glove's median level
    assert np.isfinite(pooled_reference(with_nan)).all()
    with pytest.raises(ArgumentError, match="at least 3 recordings"):
        pooled_reference(rests[:2])
    with pytest.raises(ArgumentError, match="share a grid"):
        pooled_reference([rests[0], rests[1], np.zeros((2, 2))])
    with pytest.raises(ArgumentError, match="T>0"):
        recording_rest(np.zeros((0, *GRID)), "direct")


@pytest.mark.parametrize("convention", ["direct", "inverted"])
def test_a_drift_of_the_whole_glove_moves_every_cell_s_rest_alike(convention):
    """The same recordings, still and rising 6 counts over each (the bench's drifting glove); one cell is pressed
    through the first 60% of every recording, so it rests only where the drift is highest. The drift may move
    the glove's rest as a whole (the shift follows it), not one cell against the others: read as a plain 10th
    percentile that cell sat ~3 counts higher on the drifting glove, a fifth of a press."""
    rng = np.random.default_rng(3)
    still = 257 + rng.uniform(-20, 20, GRID) + rng.normal(0, 1.0, (4, 300, *GRID)) + 2.0 * np.arange(4)[:, None, None, None]
    still[:, :180, 1, 2] += 40.0
    refs = []
    for drift in (0.0, 6.0):
        x = still + np.linspace(0, drift, 300)[None, :, None, None]
        recs = [np.asarray(1023 - r if convention == "inverted" else r, np.float16).astype(np.float32) for r in x]
        refs.append(pooled_reference([recording_rest(r, convention) for r in recs]))
    moved = refs[1] - refs[0]
    assert np.abs(moved - np.median(moved)).max() < 0.3, np.round(moved - np.median(moved), 2)


def test_shift_needs_the_glove_s_rest_and_the_file_is_checked(tmp_path):
    layout = _Layout(np.ones(GRID, bool))
    with pytest.raises(ConfigError, match="taxel_calibration"):
        NormaliseConfig(convention="direct", max_value=1023.0, baseline="shift", noise_k=5.0).validate()
    bad = tmp_path / "bad.npz"
    np.savez(bad, offset=np.full(GRID, np.nan, np.float32), gain=np.ones(GRID, np.float32))
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, offset=np.zeros((3, 3), np.float32), gain=np.ones((3, 3), np.float32))
    for path, says in ((bad, "NaN"), (wrong, "shape")):
        cfg = NormaliseConfig(convention="direct", max_value=1023.0, baseline="shift", noise_k=5.0,
                              taxel_calibration=str(path), taxel_calibration_sha256="0" * 64)
        with pytest.raises(ConfigError, match=says):
            Normaliser(cfg, layout)
    with pytest.raises(ArgumentError, match="finite"):
        write_rest_reference(tmp_path / "x.npz", np.full(GRID, np.nan))


def test_layouts_rest_writes_the_reference_from_recordings(tmp_path):
    """`htdata layouts rest LAYOUT RECORDING... OUT.npz` on .npy raw rows of the shipped 16x16 inverted glove."""
    layout = load_layout("opentouch_right_16x16")
    rng = np.random.default_rng(1)
    offsets = 3000 - rng.uniform(0, 40, layout.grid)
    paths = []
    for k in range(3):
        rows = np.round(offsets + rng.normal(0, 2, (120, *layout.grid))).astype(np.float32)
        if k == 2:
            rows[:, 5, 5] -= 300                       # inverted: a press lowers the count
        paths.append(tmp_path / f"rec{k}.npy")
        np.save(paths[-1], rows)
    out = tmp_path / "rest.npz"
    cmd = [sys.executable, "-m", "htdata.cli", "layouts", "rest", "opentouch_right_16x16", *map(str, paths), str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "3 right-hand recording(s)" in done.stdout and "baseline = \"shift\"" in done.stdout
    with np.load(out) as z:
        assert np.abs(z["offset"] - (offsets + 2 * 1.28)).max() < 3 and (z["gain"] == 1).all()
    again = subprocess.run(cmd, capture_output=True, text=True)
    assert again.returncode != 0 and "exists" in again.stderr
    two = subprocess.run([*cmd[:6], *map(str, paths[:2]), str(tmp_path / "two.npz")], capture_output=True, text=True)
    assert two.returncode != 0 and "at least 3 recordings" in two.stderr


def test_an_ingest_on_the_glove_s_rest_validates_and_renormalises(tmp_path):
    """The whole path: `htdata sample --raw-glove`, `layouts rest` over its clips, an ingest whose pipeline names
    the file with baseline = "shift", validate, and a renormalise that finds nothing to change."""
    def htdata(*args):
        done = subprocess.run([sys.executable, "-m", "htdata.cli", *map(str, args)], capture_output=True, text=True,
                              cwd=tmp_path)
        assert done.returncode == 0, (args, done.stdout, done.stderr)
        return done.stdout + done.stderr

    htdata("sample", "raw", "--raw-glove", "--quiet")
    glove = tmp_path / "raw" / "rawglove"
    clips = sorted(p for p in glove.iterdir() if p.is_dir() and p.name != "layouts")
    htdata("layouts", "--layouts", glove / "layouts", "rest", "rawknit_right_32x32", *clips, "right_rest.npz")
    pipeline = tmp_path / "shift.toml"
    pipeline.write_text(htdata("pipelines", "show", "native").split("\nhtdata")[0] + '''
[normalise.rawknit_right_32x32]
convention = "direct"
max_value = 1023
taxel_calibration = "right_rest.npz"
baseline = "shift"
noise_k = 5
''')
    htdata("ingest", "--quiet", "--pipeline", f"{pipeline}={glove}", "--layouts", glove / "layouts", "ds")
    assert "OK: dataset is sound" in htdata("validate", "ds")
    from htdata.read.metadata import DatasetMetadata
    fits = [ep["calibration_fit"]["right"] for ep in DatasetMetadata(tmp_path / "ds").episodes]
    assert len(fits) == 5 and all({"offset", "gain", "knot_rows"} <= set(f) for f in fits)   # the reference travels
    out = htdata("renormalise", "ds", "--pipeline", pipeline, "--dry-run")
    assert "unchanged" in out or "nothing" in out.lower(), out
