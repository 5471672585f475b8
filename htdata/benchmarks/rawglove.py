"""`make bench` section "raw-count glove": baselines and noise floors scored against the generator's truth.

The glove is the sample world's raw-count knit glove (htdata/synthetic/rawglove.py:
float16 counts, rest ~557 / ~566 with per-cell offsets and gains, slow
wander, drift, faults, a cross-talk column, grips of a few tens of cells). For every baseline option (none / first_frame /
rest_window (first 10 frames) / quietest (1 s span) / percentile (p5) / drift
(30 s windows)), with and without the noise floor (noise_k = 3, never below
one count), on clips that start at rest and clips that start mid-grasp:

- rest pixels > 0: share of (frame, live taxel) whose true pressure is 0
  (< REST_TRUTH) that read above 0 after normalisation;
- contact precision / recall per taxel: predicted = normalised value > 0,
  truth = true pressure >= TRUTH_LEVEL; taxel-frames with a true pressure
  in between (REST_TRUTH..TRUTH_LEVEL: a blob's faint tail) count for neither;
- frame contact precision / recall: each hand-frame by its contact rule (htdata/glove/contact.py) against
  truth = at least the rule's area of taxels with true pressure >= TRUTH_LEVEL;
- held grip kept (clips that start mid-grasp): over the clip's first second, the share of taxel-frames
  with true pressure >= TRUTH_LEVEL that read above 0 (a baseline fitted on a held grip erases it);
- cost: microseconds per two-hand frame of fitting + normalising (in memory).
Row "default": the settings a raw-count layout gets with no [normalise.<id>] table
(NormaliseConfig.from_layout_value: RAW_COUNT_DEFAULTS). The noise floor of the episode baselines
(quietest, percentile, drift) is estimated from the whole episode's resting frames; rest_window's from
its 10-frame window (it is fitted on the first chunk, before the episode is read).
Rows "file": the per-glove calibration file (`taxel_calibration`: the generator's true per-taxel offsets
and gains, measured once), alone and under a quietest-span baseline with the noise floor.

Plus a long drifting recording (10 minutes, 3 in --quick), right hand:
rest pixels > 0 over its last 30 s and contact recall over all of it, for each baseline. Plus the moving-cell rule and `layouts suggest`
against the truth (htdata/benchmarks/rawglovecells.py).
"""

from __future__ import annotations

import time

import numpy as np

from htdata.benchmarks.rawglovecells import moving_cell_rows, suggest_rows
from htdata.benchmarks.tables import table
from htdata.glove.contact import rule_for
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.synthetic.rawglove import (
    FPS,
    FULL_SCALE,
    TRUTH_LEVEL,
    GloveUnit,
    RawGloveClip,
    corpus_clips,
    glove_layout,
    make_clip,
)

REST_TRUTH = 1e-3
BASELINE_OPTIONS = (("none", {}), ("first_frame", {}), ("rest_window", {"rest_frames": 10}),
                    ("quietest", {"rest_seconds": 1.0}), ("percentile", {"baseline_percentile": 5.0}),
                    ("drift", {"drift_window_s": 30.0}))
FLOORED = ("rest_window", "quietest", "percentile", "drift")   # noise_k needs a fitted rest spread
NOISE_K = 3.0


def config_for(baseline: str, floor: bool) -> NormaliseConfig:
    if baseline == "default":        # no [normalise.<id>] table: the layout's own defaults
        return NormaliseConfig.from_layout_value(glove_layout("right").value)
    extra = dict(BASELINE_OPTIONS)[baseline]
    return NormaliseConfig(convention="direct", max_value=FULL_SCALE, baseline=baseline,
                           noise_k=NOISE_K if floor else 0.0, **extra).validate()


def normalise_clip(clip: RawGloveClip, hand: str, cfg: NormaliseConfig, unit: GloveUnit | None = None
                   ) -> np.ndarray:
    """(T, L) normalised live values of one hand of a clip, fitted as the ingest fits them (with `unit`:
    its offsets and gains as the per-glove calibration file, `taxel_calibration`, would give them)."""
    layout = glove_layout(hand)
    norm = Normaliser(cfg, layout)
    if unit is not None:
        norm.offset, norm.gain = unit.offset.astype(np.float32), (1.0 / unit.gain).astype(np.float32)
    raw = clip.counts[hand].astype(np.float32)
    rows = np.arange(len(raw))
    if cfg.per_episode:
        norm.fit_episode(raw, clip.fps, rows)
    else:
        norm.fit_baseline(raw[:64])
    values, _ = norm.apply(raw, rows=rows)
    return values[:, layout.live_mask]


def score(values: np.ndarray, pressure: np.ndarray) -> dict:
    """Counts for rest pixels > 0 and taxel contact precision / recall (see the module docstring)."""
    rest = pressure < REST_TRUTH
    truth = pressure >= TRUTH_LEVEL
    pred = values > 0
    scored = rest | truth
    return {"rest": int(rest.sum()), "rest_above_0": int((pred & rest).sum()),
            "tp": int((pred & truth).sum()), "fp": int((pred & rest & scored).sum()),
            "fn": int((~pred & truth).sum())}


def _ratios(c: dict) -> dict:
    return {"rest_pixels_above_0": c["rest_above_0"] / max(c["rest"], 1),
            "precision": c["tp"] / max(c["tp"] + c["fp"], 1) if c["tp"] + c["fp"] else None,
            "recall": c["tp"] / max(c["tp"] + c["fn"], 1) if c["tp"] + c["fn"] else None}


def _share(a: int, b: int) -> float | None:
    return a / b if b else None


def held_grip(values: np.ndarray, pressure: np.ndarray, fps: float) -> tuple[int, int]:
    """(kept, held): over the first second, true-contact taxel-frames that read above 0, and all of them."""
    n = int(round(fps))
    held = pressure[:n] >= TRUTH_LEVEL
    return int((held & (values[:n] > 0)).sum()), int(held.sum())


def contact_rule(cfg: NormaliseConfig):
    """The frame contact rule htdata.glove.contact gives this calibration on the sample glove."""

    layout = glove_layout("right")
    return rule_for(cfg.to_dict(), layout.value, int(layout.live_mask.sum()))


# rows with the per-glove calibration file (offset + gain measured once): (label, baseline, noise floor)
CALIBRATION_FILE_ROWS = (("file", "none", False), ("file + quietest", "quietest", True))


def clip_rows(clips: list[RawGloveClip], units: dict[str, GloveUnit] | None = None) -> list[dict]:
    """One row per (baseline option or calibration-file row, noise floor, clip start): see the module docstring."""
    plans = [("default", "default", True, False)]
    plans += [(b, b, floor, False) for b, _ in BASELINE_OPTIONS for floor in (False, True)
              if not floor or b in FLOORED]
    if units:
        plans += [(label, b, floor, True) for label, b, floor in CALIBRATION_FILE_ROWS]
    rows = []
    for label, baseline, floor, with_file in plans:
        cfg = config_for(baseline, floor)
        for start in ("rest", "mid_grasp"):
            total = {"rest": 0, "rest_above_0": 0, "tp": 0, "fp": 0, "fn": 0}
            rule = contact_rule(cfg)
            frames_hit = {"tp": 0, "fp": 0, "fn": 0}
            frames, seconds, grip = 0, 0.0, [0, 0]
            for clip in (c for c in clips if c.start == start):
                t0 = time.perf_counter()
                values = {h: normalise_clip(clip, h, cfg, units[h] if with_file else None)
                          for h in clip.counts}
                seconds += time.perf_counter() - t0
                frames += clip.n_frames
                for h, v in values.items():
                    pressure = clip.pressure[h][:, glove_layout(h).live_mask]
                    c = score(v, pressure)
                    total = {k: total[k] + c[k] for k in total}
                    grip = [a + b for a, b in zip(grip, held_grip(v, pressure, clip.fps))]
                    pred, truth = rule.frames(v), (pressure >= TRUTH_LEVEL).sum(axis=1) >= rule.min_taxels
                    frames_hit["tp"] += int((pred & truth).sum())
                    frames_hit["fp"] += int((pred & ~truth).sum())
                    frames_hit["fn"] += int((~pred & truth).sum())
            rows.append({"baseline": label, "noise_floor": f"noise_k={cfg.noise_k:g}" if cfg.noise_k else "none",
                         "held_grip_kept": _share(*grip) if start == "mid_grasp" else None,
                         "clips": start, "frames": frames, **_ratios(total),
                         "us_per_frame": 1e6 * seconds / max(frames, 1), "contact_rule": rule.describe(),
                         "frame_precision": _share(frames_hit["tp"], frames_hit["tp"] + frames_hit["fp"]),
                         "frame_recall": _share(frames_hit["tp"], frames_hit["tp"] + frames_hit["fn"])})
    return rows


def drift_rows(minutes: float, seed: int) -> dict:
    """A long right-hand recording that drifts: rest pixels > 0 over its last 30 s, per baseline (floor on)."""
    unit = GloveUnit.make("right", seed)
    n = int(round(minutes * 60 * FPS))
    clip = make_clip("drift", "power_grasp", n, "rest", seed, {"right": unit})
    live = glove_layout("right").live_mask
    tail = slice(n - int(30 * FPS), n)
    out = []
    for baseline, _ in BASELINE_OPTIONS:
        if baseline not in FLOORED:
            continue
        values = normalise_clip(clip, "right", config_for(baseline, True))
        c = score(values[tail], clip.pressure["right"][tail][:, live])
        whole = _ratios(score(values, clip.pressure["right"][:, live]))   # a floor widened by drift costs recall
        out.append({"baseline": baseline, "rest_pixels_above_0_last_30s": _ratios(c)["rest_pixels_above_0"],
                    "recall": whole["recall"]})
    return {"minutes": minutes, "frames": n, "rows": out}


def rawglove_rows(quick: bool, seed: int) -> dict:
    units, clips = corpus_clips(seed)
    if quick:
        clips = [c for c in clips if c.n_frames <= 270][:3] + [c for c in clips if c.start == "mid_grasp"][:1]
    return {"clips": clip_rows(clips, units), "drift": drift_rows(3.0 if quick else 10.0, seed),
            "truth_level": TRUTH_LEVEL, "noise_k": NOISE_K, "default": config_for("default", True).to_dict(),
            "moving_cells": moving_cell_rows(clips, units), "suggest": suggest_rows(clips, units)}


def rawglove_markdown(d: dict) -> list[str]:
    lines = [f"Sample raw-count glove (htdata/synthetic/rawglove.py), both hands. Rest pixels > 0: share of live "
             f"taxel-frames with true pressure 0 reading above 0. Precision / recall per taxel: predicted = value "
             f"> 0, truth = true pressure >= {d['truth_level']}. Cost: fit + normalise, in memory.", ""]
    rows = [{k: ("-" if v is None else v) for k, v in r.items()} for r in d["clips"]]   # no prediction: no precision
    lines += table(rows, [("baseline", "baseline"), ("noise_floor", "noise floor"), ("clips", "clips start"),
                                ("frames", "frames"), ("rest_pixels_above_0", "rest pixels > 0"),
                                ("precision", "precision"), ("recall", "recall"),
                                ("frame_precision", "frame contact precision"), ("frame_recall", "frame contact recall"),
                                ("held_grip_kept", "held grip kept"), ("us_per_frame", "us/frame")])
    lines += ["Frame contact: the hand's contact rule (htdata/glove/contact.py) against truth = at least that many "
              "taxels with true pressure >= the truth level; with a noise floor: " +
              next((r["contact_rule"] for r in d["clips"] if r["noise_floor"] != "none"), "-") +
              "; without: " + next((r["contact_rule"] for r in d["clips"] if r["noise_floor"] == "none"), "-") + ".", ""]
    dr = d["drift"]
    lines += ["", f"Drifting recording: {dr['minutes']:g} minutes ({dr['frames']} frames), right hand, "
                  f"noise_k = {d['noise_k']:g}: rest pixels > 0 over the last 30 s.", ""]
    lines += table(dr["rows"], [("baseline", "baseline"), ("rest_pixels_above_0_last_30s", "rest pixels > 0"),
                                ("recall", "recall (whole recording)")])
    return lines + [""] + cells_markdown(d)


def cells_markdown(d: dict) -> list[str]:
    """The moving-cell and suggest tables (htdata/benchmarks/rawglovecells.py)."""
    if "moving_cells" not in d:
        return []
    dash = lambda rows: [{k: ("-" if v is None else v) for k, v in r.items()} for r in rows]   # noqa: E731
    lines = ["Moving cells: unmapped cells of a first-draft layout (the thumb tip forgotten, no unused cells) that "
             "move, against truth = a responding sensor pressed beyond quiet (5 counts), over every clip and hand. "
             "False ones split into ghosts (the cross-talk column, cells falling beside a press) / loud cells (they do "
             "move) and resting cells.", ""]
    lines += table(dash(d["moving_cells"]), [("rule", "rule"), ("pressed", "pressed cells"), ("found", "found"),
                                            ("precision", "precision"), ("recall", "recall"),
                                            ("false_ghost_or_loud", "false: ghost / loud"),
                                            ("false_resting", "false: resting")])
    lines += ["", "`htdata layouts suggest` from every clip of a hand against the true sensor areas.", ""]
    lines += table(dash(d["suggest"]), [("hand", "hand"), ("blocks", "blocks"), ("true_areas", "true areas"),
                                       ("exact_areas", "exactly a true area"), ("precision", "cell precision"),
                                       ("recall", "cell recall"), ("recall_of_pressed", "recall of pressed cells"),
                                       ("left_out", "moving cells left out")])
    return lines + [""]
