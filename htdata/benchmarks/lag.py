"""The tactile-video lag estimator (htdata/source/lag.py): error against known lags, cost per episode minute.

Episodes of the sample world (htdata.synthetic.world: every task, its contact
visible in the RGB) are written as native recordings whose glove clock runs
`lag` off the video clock while recording.json claims the clocks agree
(clock_offset_ns 0): `write_shifted_native`, also used by tests/source/test_lag.py.
Each is estimated through the native adapter exactly as an ingest with
`[sync] lag = "estimate"` does (`estimate_episode_lag`: a second pass that
decodes the video and reads every tactile row), and timed; the estimator
alone (`estimate_lag` on the thumbnails and contact series) is timed apart.
Error = |estimated - known lag|, against one video frame (33.3 ms at 30
fps). Recordings whose glove never feels anything must be declined.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

from htdata.benchmarks.sources import discover
from htdata.benchmarks.tables import fmt as _fmt
from htdata.benchmarks.tables import table
from htdata.errors import ArgumentError
from htdata.glove.glovevalue import is_inverted
from htdata.glove.layouts import load_layout
from htdata.glove.normalise import Normaliser
from htdata.source.lag import _contact_series, _rgb_series, estimate_episode_lag, estimate_lag
from htdata.synthetic.corpus import native_raw
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from htdata.synthetic.tasks import TASKS
from htdata.synthetic.world import EpisodeSpec, World

SHIFTS_MS = (-200.0, -50.0, 0.0, 100.0)
FPS = 30.0
TACTILE_HZ = 100.0
IMAGE = (240, 240)
LAYOUTS = {("right",): {"right": "opentouch_right_16x16"},
           ("left", "right"): {"left": "touchanything_left_21x21", "right": "touchanything_right_21x21"}}


def write_shifted_native(folder: Path, task: str, seed: int, n_frames: int, lag_ms: float,
                         hands: tuple[str, ...] = ("right",), touching: bool = True,
                         storage: str = "mp4", image: tuple[int, int] = IMAGE, repeats: int = 1) -> Path:
    """A native recording of sample-world episodes whose glove stamps run `lag_ms` late.

    `repeats` episodes of `task` (seeds seed, seed+1, ...; n_frames each at
    30 fps) one after the other, like a session of several grasps. Glove:
    100 Hz rows on the video clock + lag (clock_offset_ns 0). `touching=False`:
    the glove feels nothing (rest values + sensor noise) while the video
    still shows the hand moving.
    """
    from itertools import chain


    worlds = [World(EpisodeSpec(task, "lab_bench", int(seed) + r, int(n_frames), FPS, tuple(hands)).validate())
              for r in range(repeats)]
    spec = worlds[0].spec
    rng = np.random.default_rng([int(seed), int(n_frames), int(repeats)])
    video_start = 10**12
    t_glove = spec.frame_times(TACTILE_HZ)
    t_all = np.concatenate([t_glove + r * spec.duration_s for r in range(repeats)])
    glove_ts = video_start + np.round(t_all * 1e9).astype(np.int64) + int(round(lag_ms * 1e6))
    rec_hands = {}
    for hand, layout_id in LAYOUTS[spec.hands].items():
        layout = load_layout(layout_id)
        fill = float("nan") if not is_inverted(layout.value.get("convention")) else 0.0
        contact = np.concatenate([w.contact_grids(layout, hand, t_glove, fill=fill) for w in worlds])
        if not touching:
            contact = np.where(np.isnan(contact), contact, 0.0).astype(np.float32)
        rec_hands[hand] = NativeHand(layout_id, native_raw(contact, layout, rng), glove_ts)
    video_times = spec.frame_times()
    t_video = np.concatenate([video_times + r * spec.duration_s for r in range(repeats)])
    write_native_recording(Path(folder), NativeRecording(
        task=task, scene="lab_bench", video_frames=chain.from_iterable(w.render_frames(video_times, image)
                                                                       for w in worlds),
        video_timestamps_ns=video_start + np.round(t_video * 1e9).astype(np.int64),
        hands=rec_hands, video_storage=storage, extra={"seed": int(seed), "true_lag_ms": float(lag_ms)}))
    return Path(folder)


def planned_episode(folder: Path, pipeline: str = "native"):
    """(pipeline config, adapter, planned ref) of the one recording under `folder`."""

    cfg, adapter, refs = discover(pipeline, folder)
    if len(refs) != 1:
        raise ArgumentError(f"{folder}: expected one recording, found {len(refs)}")
    return cfg, adapter, refs[0]


def _core_ms(cfg, adapter, ref) -> float:
    """Wall ms of `estimate_lag` alone, on inputs read beforehand (untimed)."""

    with adapter.open(ref, cfg.adapter.params) as streams:
        tactile = {}
        for h in ref.hands:
            layout = load_layout(ref.layout_files[h])
            tactile[h] = _contact_series(streams, h, Normaliser(cfg.normalise_for(layout), layout))
        t_rgb, thumbs = _rgb_series(streams)
    t0 = time.perf_counter()
    estimate_lag(t_rgb, thumbs, tactile, cfg.sync.max_lag_ns)
    return (time.perf_counter() - t0) * 1e3


def measure(folder: Path, true_lag_ms: float, n_frames: int) -> dict:
    """One recording: the estimate (as an ingest with lag = "estimate" makes it), its error and cost."""

    cfg, adapter, ref = planned_episode(folder)
    cfg = cfg.with_overrides(['sync.lag="estimate"'])
    t0 = time.perf_counter()
    est = estimate_episode_lag(ref, adapter, cfg.adapter.params, cfg.normalise_settings(), cfg.sync, list(ref.hands))
    total_ms = (time.perf_counter() - t0) * 1e3
    minutes = n_frames / FPS / 60.0
    err = None if est.lag_ns is None else abs(est.lag_ns / 1e6 - true_lag_ms)
    applied = not est.why and est.confidence >= cfg.sync.min_confidence
    return {"true_lag_ms": true_lag_ms, "lag_ms": None if est.lag_ns is None else est.lag_ns / 1e6,
            "abs_error_ms": err, "confidence": est.confidence, "applied": applied, "why": est.why,
            "frames": n_frames, "ms_per_minute": total_ms / minutes,
            "core_ms_per_minute": _core_ms(cfg, adapter, ref) / minutes}


def _summary(rows: list[dict], frame_ms: float) -> dict:
    applied = [r for r in rows if r["applied"]]
    errs = np.array([r["abs_error_ms"] for r in applied], dtype=np.float64)
    return {"episodes": len(rows), "applied": len(applied),
            "within_one_frame": int((errs <= frame_ms).sum()) if errs.size else 0,
            "median_abs_error_ms": float(np.median(errs)) if errs.size else None,
            "max_abs_error_ms": float(errs.max()) if errs.size else None}


def lag_rows(work: Path, quick: bool = False, seed: int = 0) -> dict:
    """Every task x SHIFTS_MS (one or two hands), untouched gloves, and one long episode for the cost."""

    base = Path(work) / "lag"
    if base.exists():
        shutil.rmtree(base)
    tasks = tuple(TASKS)[:2] if quick else tuple(TASKS)
    n_frames, long_repeats = (60, 5) if quick else (90, 20)    # long: a 10 s / 60 s session of grasps
    frame_ms = 1e3 / FPS
    rows, by_shift = [], {}
    for k, task in enumerate(tasks):
        hands = ("left", "right") if k % 3 == 2 else ("right",)
        for shift in SHIFTS_MS:
            folder = write_shifted_native(base / f"{task}_{shift:+.0f}", task, seed + k, n_frames, shift, hands)
            row = {"task": task, "hands": "+".join(hands), **measure(folder, shift, n_frames)}
            rows.append(row)
            by_shift.setdefault(shift, []).append(row)
    still = []
    for k, task in enumerate(tasks[:2]):
        folder = write_shifted_native(base / f"{task}_still", task, seed + k, n_frames, 0.0, touching=False)
        still.append({"task": task, **measure(folder, 0.0, n_frames)})
    folder = write_shifted_native(base / "long", tasks[0], seed, n_frames, 100.0, repeats=long_repeats)
    long_row = {"task": tasks[0], **measure(folder, 100.0, n_frames * long_repeats)}
    shifts = [{"true_lag_ms": s, **_summary(rs, frame_ms)} for s, rs in by_shift.items()]
    return {"frame_ms": frame_ms, "episode_frames": n_frames, "shifts": shifts,
            "all": _summary(rows, frame_ms), "rows": rows,
            "no_contact": {"episodes": len(still), "declined": sum(not r["applied"] for r in still),
                           "rows": still},
            "cost": {"short_ms_per_minute": float(np.median([r["ms_per_minute"] for r in rows])),
                     "short_core_ms_per_minute": float(np.median([r["core_ms_per_minute"] for r in rows])),
                     "long_frames": n_frames * long_repeats, "long_grasps": long_repeats,
                     "long_ms_per_minute": long_row["ms_per_minute"],
                     "long_core_ms_per_minute": long_row["core_ms_per_minute"],
                     "long_abs_error_ms": long_row["abs_error_ms"], "long_applied": long_row["applied"]}}


def lag_markdown(d: dict) -> list[str]:
    """REPORT.md lines of the section (htdata/benchmarks/report.py renders them under its heading)."""

    lines = [f"Sample-world native recordings ({d['episode_frames']} frames at 30 fps, glove 100 Hz) whose glove "
             f"clock runs a known lag off the video; `[sync] lag = \"estimate\"` as an ingest runs it. Error = "
             f"|estimated - known| over the applied (confident) estimates; one video frame = {d['frame_ms']:.1f} ms.", ""]
    lines += table(d["shifts"] + [{"true_lag_ms": "all", **d["all"]}],
                   [("true_lag_ms", "known lag ms"), ("episodes", "episodes"), ("applied", "applied"),
                    ("within_one_frame", "within 1 frame"), ("median_abs_error_ms", "median abs error ms"),
                    ("max_abs_error_ms", "max abs error ms")])
    c, nc = d["cost"], d["no_contact"]
    lines += [f"Gloves that feel nothing: {nc['declined']} of {nc['episodes']} declined (nothing applied).", "",
              f"Cost per episode minute: {_fmt(c['short_ms_per_minute'])} ms on the short episodes "
              f"(estimator alone {_fmt(c['short_core_ms_per_minute'])} ms; the rest is the second video decode and "
              f"tactile read), {_fmt(c['long_ms_per_minute'])} ms on one {c['long_frames']}-frame episode of {c['long_grasps']} grasps (estimator "
              f"alone {_fmt(c['long_core_ms_per_minute'])} ms; abs error {_fmt(c['long_abs_error_ms'])} ms).", ""]
    return lines
