"""`make bench` section "real glove": the rules measured on real raw-count recordings (issue 34).

The recordings are a folder given by an explicit path (`htdata bench
--real-glove DIR`; the Makefile passes ../shared/real_glove when it exists).

The measures, per (clip, hand), with raw counts over the layout's live cells
(the folder's README defines them; the truth is the raw counts alone):

- pressed: raw minus the cell's own 10th percentile over the clip > PRESSED
  counts; quiet: < QUIET counts;
- rest leakage: in the REST_SHARE of frames with the lowest mean raw count,
  the share of quiet cells whose normalised value is > 0 (and beside it the
  share of covered canvas pixels > 0 in those frames);
- held grip kept: the share of pressed (cell, frame) read > 0, over all
  frames and over the first START_FRAMES frames of the pairs that start
  mid-grasp (>= MID_GRASP pressed cells on average there, and >= MID_GRASP_GAIN
  more than in the clip's least-pressed window of START_FRAMES);
- quiet false contact: the share of quiet (cell, frame) read > 0;
- contact share: frames with >= CONTACT_CELLS pressed cells, against the
  share `htdata stats` reports for the hand after a real ingest;
- trim --idle: frames `htdata trim --idle --dry-run` would cut that hold
  >= CONTACT_CELLS pressed cells (target: none);
- moving cells and `layouts suggest`: htdata/benchmarks/realglovecells.py.

The clips (a folder, or the sample glove's corpus) are htdata/benchmarks/realclips.py's.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htdata.benchmarks.realclips import HANDS, RealClip, load_real_glove
from htdata.benchmarks.realglovecells import cells_markdown, cells_rows
from htdata.benchmarks.realglovev2 import (
    DECLARED_PRESS_GLOVES,
    DERIVED_GLOVES,
    config_for,
    derived_clips,
    derived_counts,
    derived_layout,
    glove_truths,
    hand_counts_v2,
    sensitivity_rows,
    v2_summary,
)
from htdata.benchmarks.tables import table
from htdata.curate.idle import IdleConfig, plan_idle
from htdata.glove.layouts import Layout
from htdata.glove.normalise import Normaliser
from htdata.glove.normaliseconfig import BASELINES, NOISE_K_BASELINES, RAW_COUNT_DEFAULTS, NormaliseConfig
from htdata.glove.rasterise import Rasteriser
from htdata.glove.restreference import pooled_reference, recording_rest, write_rest_reference
from htdata.ingest.pipeline import load_pipeline
from htdata.ingest.plan import Source
from htdata.ingest.run import ingest
from htdata.inspect.stats import episode_stats
from htdata.read.reader import DatasetReader
from htdata.synthetic.rawfacts import (  # the truth's one home, beside the facts it defines
    CONTACT_CELLS,
    MID_GRASP,
    MID_GRASP_GAIN,
    PRESSED,
    QUIET,
    REST_SHARE,
    START_FRAMES,
    TRUTH_PERCENTILE,
)

MOVING_STILL = 10.0      # counts: no moving-cell flag on a cell ranging less (realglovecells.QUIET_RANGE)
TARGETS = {"rest_leakage_mean": 0.02, "rest_leakage_worst": 0.05, "held_grip_kept": 0.90,
           "held_grip_kept_start": 0.90, "quiet_false_contact": 0.02, "contact_share_error": 0.10,
           "moving_precision": 0.90, "suggest_blocks": 9, "suggest_precision": 0.90, "suggest_recall": 0.90}
NOISE_K = RAW_COUNT_DEFAULTS["noise_k"]
POOLED = ("pooled",)     # the plan of the default row: baseline "shift" on the rest pooled over every clip given
DEFAULT_TOGETHER = "default, clips ingested together (the glove's rest)"
DEFAULT_ALONE = "default, one recording alone (no [normalise] table)"
# every baseline option beside the default (no [normalise] table): floored (as by default) where a floor can be fitted
BASELINE_ROWS = tuple((b, NOISE_K if b in NOISE_K_BASELINES else 0.0) for b in BASELINES)


@dataclass
class HandTruth:
    """What the raw counts alone say about one (clip, hand), over the layout's live cells."""
    raw: np.ndarray          # (T, L) float32 counts
    pressed: np.ndarray      # (T, L) bool
    quiet: np.ndarray        # (T, L) bool
    rest_frames: np.ndarray  # indices of the hand's lowest-mean frames
    mid_grasp: bool

    @classmethod
    def of(cls, raw: np.ndarray, live: np.ndarray) -> "HandTruth":
        x = np.asarray(raw, np.float32)[:, live]
        above = x - np.percentile(x, TRUTH_PERCENTILE, axis=0)
        pressed = above > PRESSED
        n = pressed.sum(axis=1)
        k = min(START_FRAMES, len(n))
        least = np.convolve(n, np.ones(k) / k, mode="valid").min()
        start = n[:k].mean()
        rest = np.argsort(x.mean(axis=1), kind="stable")[: max(1, int(round(REST_SHARE * len(x))))]
        return cls(x, pressed, above < QUIET, rest, bool(start >= MID_GRASP and start >= least + MID_GRASP_GAIN))

    @property
    def contact(self) -> np.ndarray:
        """(T,) bool: frames with at least CONTACT_CELLS pressed cells."""
        return self.pressed.sum(axis=1) >= CONTACT_CELLS


def left_out_reference(cfg: NormaliseConfig, others: list[np.ndarray], path: Path) -> NormaliseConfig:
    """`cfg` with the glove's rest reference pooled over `others` (the other clips' raw rows of this glove
    hand: leave-one-out) written to `path` as its taxel calibration (htdata.glove.restreference)."""
    write_rest_reference(path, pooled_reference([recording_rest(r, cfg.convention) for r in others]))
    return dataclasses.replace(cfg, taxel_calibration=str(path),
                               taxel_calibration_sha256=hashlib.sha256(path.read_bytes()).hexdigest()).validate()


def normalised(raw: np.ndarray, layout: Layout, cfg: NormaliseConfig, fps: float) -> np.ndarray:
    """(T, H, W) values of one hand's raw rows, fitted as the ingest fits them (whole episode, or first chunk)."""
    norm = Normaliser(cfg, layout)
    x = np.asarray(raw, np.float32)
    rows = np.arange(len(x))
    if cfg.per_episode:
        norm.fit_episode(x, fps, rows)
    else:
        norm.fit_baseline(x[:64])
    return norm.apply(x, rows=rows)[0]


def hand_counts(truth: HandTruth, values: np.ndarray, layout: Layout, raster: Rasteriser) -> dict:
    """Counts behind the measures of one (clip, hand): numerators and denominators, mergeable by addition."""
    v = values[:, layout.live_mask] > 0
    rest = truth.rest_frames
    maps = raster.render(values[rest])
    covered = raster.coverage > 0
    out = {"rest_quiet": int(truth.quiet[rest].sum()), "rest_quiet_lit": int((truth.quiet[rest] & v[rest]).sum()),
           "rest_pixels": int(covered.sum()) * len(rest), "rest_pixels_lit": int((maps[:, covered] > 0).sum()),
           "pressed": int(truth.pressed.sum()), "pressed_kept": int((truth.pressed & v).sum()),
           "quiet": int(truth.quiet.sum()), "quiet_lit": int((truth.quiet & v).sum()),
           "start_pressed": 0, "start_kept": 0}
    if truth.mid_grasp:
        s = slice(0, START_FRAMES)
        out["start_pressed"] = int(truth.pressed[s].sum())
        out["start_kept"] = int((truth.pressed[s] & v[s]).sum())
    return out


def _ratio(a: int, b: int) -> float | None:
    return a / b if b else None


def normalise_rows(clips: list[RealClip], layouts: dict[str, Layout], baselines: bool | tuple[str, ...] = True,
                   gloves: tuple = DERIVED_GLOVES) -> list[dict]:
    """One row per (glove, setting): the real glove and each derived glove (realglovev2.DERIVED_GLOVES), the
    default and then every baseline (`baselines` True), none (False) or those named; version 1's measures and
    version 2's side by side, both against the original presses."""
    chosen = BASELINE_ROWS if baselines is True else [r for r in BASELINE_ROWS if baselines and r[0] in baselines]
    # the default: clips ingested together pool the glove's rest (htdata.ingest.gloverest); one recording alone
    # gets the raw-count default (its cells' rest from itself)
    plans = [(DEFAULT_TOGETHER, POOLED), (DEFAULT_ALONE, None)] + [(f"{b}" + (" on the glove's rest (leave-one-out)" if b == "shift"
                                                                 else "") + (f", noise_k={k:g}" if k else ""), (b, k))
                                                          for b, k in chosen]
    rasters = {h: Rasteriser(layouts[h]) for h in HANDS}
    truths = {(c.clip, h): HandTruth.of(c.hand(h), layouts[h].live_mask) for c in clips for h in HANDS}
    truths2 = {h: glove_truths(clips, h, layouts[h].live_mask) for h in HANDS}
    rows = []
    tmp = tempfile.TemporaryDirectory(prefix="htdata-realglove-")
    for glove in gloves:
        counts = {(c.clip, h): derived_counts(glove, c.hand(h), truths2[h][c.clip], layouts[h].live_mask)
                  for c in clips for h in HANDS}
        glayouts = {h: derived_layout(glove, layouts[h]) for h in HANDS}
        for label, plan in plans:
            total, total2, leaks, leaks2, seconds, frames = {}, {}, [], [], 0.0, 0
            for clip in clips:
                for h in HANDS:
                    cfg = config_for(glayouts[h], ("shift", NOISE_K) if plan is POOLED else plan)
                    if plan is POOLED:             # what an ingest of all the clips does by default
                        cfg = left_out_reference(cfg, [counts[(c.clip, h)] for c in clips],
                                                 Path(tmp.name) / f"{glove[0]}-{h}-all.npz")
                    elif cfg.baseline == "shift":  # the glove's rest from its OTHER clips: the check can fail
                        cfg = left_out_reference(cfg, [counts[(c.clip, h)] for c in clips if c.clip != clip.clip],
                                                 Path(tmp.name) / f"{glove[0]}-{h}-{clip.clip}.npz")
                    t0 = time.perf_counter()
                    values = normalised(counts[(clip.clip, h)], glayouts[h], cfg, clip.fps)
                    seconds += time.perf_counter() - t0
                    frames += len(values)
                    c = hand_counts(truths[(clip.clip, h)], values, layouts[h], rasters[h])
                    c2 = hand_counts_v2(truths2[h][clip.clip], values, layouts[h], rasters[h])
                    total = {k: total.get(k, 0) + n for k, n in c.items()}
                    total2 = {k: total2.get(k, 0) + n for k, n in c2.items()}
                    leaks.append((f"clip {clip.clip} {h}", _ratio(c["rest_quiet_lit"], c["rest_quiet"]) or 0.0))
                    leaks2.append((f"clip {clip.clip} {h}", _ratio(c2["rest_quiet_lit"], c2["rest_quiet"]) or 0.0))
            worst = max(leaks, key=lambda x: x[1])
            rows.append({"glove": glove[0], "setting": label, **v2_summary(total2, leaks2),
                         "rest_leakage_mean": float(np.mean([v for _, v in leaks])),
                         "rest_leakage_worst": worst[1], "rest_leakage_worst_at": worst[0],
                         "rest_canvas_lit": _ratio(total["rest_pixels_lit"], total["rest_pixels"]),
                         "held_grip_kept": _ratio(total["pressed_kept"], total["pressed"]),
                         "held_grip_kept_start": _ratio(total["start_kept"], total["start_pressed"]),
                         "quiet_false_contact": _ratio(total["quiet_lit"], total["quiet"]),
                         "us_per_hand_frame": 1e6 * seconds / max(frames, 1)})
    tmp.cleanup()
    return rows


def write_native_clips(clips: list[RealClip], layouts: dict[str, Layout], root: Path) -> Path:
    """Glove-only native recordings of the clips under root/recordings (layout files beside them in
    root/layouts); returns the recordings folder."""
    rec_dir, lay_dir = root / "recordings", root / "layouts"
    for d in (rec_dir, lay_dir):
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
    for h in HANDS:
        (lay_dir / f"{layouts[h].layout_id}.json").write_text(json.dumps(layouts[h].to_dict(), indent=1))
    for clip in clips:
        folder = rec_dir / f"clip_{clip.clip}"
        folder.mkdir()
        ts = (np.arange(len(clip.counts)) * (1e9 / clip.fps)).astype(np.int64)
        hands = {}
        for h in HANDS:
            np.savez(folder / f"tactile_{h}.npz", values=clip.hand(h), timestamps_ns=ts)
            hands[h] = {"layout": layouts[h].layout_id, "file": f"tactile_{h}.npz"}
        task = "".join(ch if ch.isalnum() else "_" for ch in clip.label.lower()).strip("_")
        (folder / "recording.json").write_text(json.dumps(
            {"format": "htdata-native", "format_version": 1, "task": task, "scene": "real_glove", "hands": hands}))
    return rec_dir


def dataset_rows(clips: list[RealClip], layouts: dict[str, Layout], work: Path,
                 truth_clips: list[RealClip] | None = None) -> dict:
    """A default ingest of the clips (no [normalise] table), then `htdata stats` contact share per hand against
    the truth (of `truth_clips`, the original presses of a derived glove's clips), and the pressed frames
    `htdata trim --idle --dry-run` would cut."""
    rec_dir = write_native_clips(clips, layouts, work)
    out = work / "dataset"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    ingest([Source(load_pipeline("native"), rec_dir)], out, workers=0, progress=False,
           layout_dirs=(str(work / "layouts"),), command="htdata bench (real glove)")
    ingest_s = time.perf_counter() - t0
    by_id = {f"nat-clip_{c.clip}": c for c in (truth_clips or clips)}
    # version 2's truth: presses above the glove's rest (pooled over the original clips), not the clip's own
    truths = {h: glove_truths(truth_clips or clips, h, layouts[h].live_mask) for h in HANDS}
    shares, cut_pressed, cut_frames = [], 0, 0
    with DatasetReader(out) as reader:
        per_episode, _ = episode_stats(reader, cache_dir=None)
        cuts = {c.episode: c for c in plan_idle(reader, IdleConfig(), cache_dir=None)}
        for rec, st in zip(reader.episodes, per_episode):
            clip = by_id[rec["episode_id"]]
            contact = np.zeros(len(clip.counts), bool)
            for h in HANDS:
                truth = truths[h][clip.clip].pressed.sum(axis=1) >= CONTACT_CELLS
                hs = st["hands"][h]
                shares.append({"clip": clip.clip, "hand": h, "truth": float(truth.mean()),
                               "stats": hs["contact_frames"] / max(hs["frames"], 1)})
                contact |= truth
            cut = cuts[rec["episode_id"]]
            if cut.keep is not None:
                dropped = np.ones(len(clip.counts), bool)
                dropped[cut.keep.start:cut.keep.stop] = False
                cut_frames += int(dropped.sum())
                cut_pressed += int((dropped & contact).sum())
    errors = {h: max(abs(s["stats"] - s["truth"]) for s in shares if s["hand"] == h) for h in HANDS}
    return {"ingest_s": ingest_s, "frames": int(sum(len(c.counts) for c in clips)), "contact_share": shares,
            "contact_share_error": errors, "idle_cut_frames": cut_frames, "idle_cut_pressed_frames": cut_pressed}


def realglove_rows(folder: str | Path | None, work: Path, quick: bool = False) -> dict:
    """The section: every measure on the folder's clips (a note without a folder)."""
    if folder is None:
        return {"skipped": "no real-glove folder given (htdata bench --real-glove DIR; the Makefile passes "
                           "../shared/real_glove when it exists)"}
    clips, layouts = load_real_glove(folder)
    if quick:
        clips = sorted(clips, key=lambda c: len(c.counts))[:3]
    work.mkdir(parents=True, exist_ok=True)
    return {"folder": str(folder), "clips": len(clips), "frames": int(sum(len(c.counts) for c in clips)),
            "targets": TARGETS, "normalise": normalise_rows(clips, layouts),
            "sensitivity": sensitivity_rows(clips, layouts),
            "dataset": dataset_rows(clips, layouts, work), "dataset_gloves": [
                {"glove": g[0], **dataset_rows(*derived_clips(g, clips, layouts), work / f"glove_{k}", clips)}
                for k, g in enumerate(DERIVED_GLOVES[1:] + DECLARED_PRESS_GLOVES, 1)],
            **cells_rows(clips, layouts, leave_one_out=not quick)}


def realglove_markdown(d: dict) -> list[str]:
    if "skipped" in d:
        return [f"Skipped: {d['skipped']}.", ""]
    dash = lambda rows: [{k: ("-" if v is None else v) for k, v in r.items()} for r in rows]   # noqa: E731
    t = d["targets"]
    lines = [f"{d['clips']} real clips ({d['frames']} frames, both hands) from {d['folder']}; measures and targets "
             f"from its README (htdata/benchmarks/realglove.py). Targets: rest leakage mean <= "
             f"{t['rest_leakage_mean']:.0%}, worst <= {t['rest_leakage_worst']:.0%}; held grip kept >= "
             f"{t['held_grip_kept']:.2f} (all frames and the start of mid-grasp clips); quiet false contact <= "
             f"{t['quiet_false_contact']:.0%}.", ""]
    lines += ["Version 2 (rest from the glove: htdata/benchmarks/realglovev2.py), every glove derived from the clips "
              "with the same truth (the original presses); version 1's columns (rest from the clip) beside it.", ""]
    lines += table(dash(d["normalise"]), [
        ("glove", "glove"), ("setting", "setting"), ("v2_rest_leakage_mean", "v2 rest leakage mean"),
        ("v2_rest_leakage_worst", "v2 worst"), ("v2_rest_canvas_lit", "v2 rest canvas px > 0"),
        ("v2_held_grip_kept", "v2 held grip kept"), ("v2_held_grip_kept_start", "v2 kept, start of mid-grasp"),
        ("v2_held_grip_kept_held_cells", "v2 kept, cells held through"),
        ("v2_quiet_false_contact", "v2 quiet false contact"),
        ("rest_leakage_mean", "v1 rest leakage mean"), ("rest_leakage_worst", "v1 worst"),
        ("held_grip_kept", "v1 held grip kept"), ("held_grip_kept_start", "v1 kept, start"),
        ("quiet_false_contact", "v1 quiet false contact"), ("us_per_hand_frame", "us / hand-frame")])
    ds = d["dataset"]
    err = ", ".join(f"{h} {e:.3f}" for h, e in ds["contact_share_error"].items())
    lines += ["", f"Default ingest of the clips ({ds['frames']} frames, {ds['ingest_s']:.1f} s, inline): `htdata "
                  f"stats` contact share per (clip, hand) against the truth (frames with >= {CONTACT_CELLS} pressed "
                  f"cells): worst error {err} (target <= {t['contact_share_error']:.2f}). `htdata trim --idle "
                  f"--dry-run` would cut {ds['idle_cut_frames']} frames, {ds['idle_cut_pressed_frames']} of them "
                  f"with >= {CONTACT_CELLS} pressed cells (target 0).", ""]
    lines += table(ds["contact_share"], [("clip", "clip"), ("hand", "hand"), ("truth", "contact share, truth"),
                                         ("stats", "htdata stats")])
    lines += ["", "The same default ingest of each derived glove, against the original presses (rows with value.press: "
                  "the layout declares the glove's sensitivity):", ""]
    lines += table([{"glove": g["glove"], "left": g["contact_share_error"]["left"],
                     "right": g["contact_share_error"]["right"], "cut": g["idle_cut_frames"],
                     "cut_pressed": g["idle_cut_pressed_frames"]} for g in d.get("dataset_gloves", [])],
                   [("glove", "glove"), ("left", "contact share worst error, left"), ("right", "right"),
                    ("cut", "trim --idle cuts"), ("cut_pressed", "of them >= 7 pressed cells")])
    lines += ["", f"What the clips say about each glove's sensitivity (medians over clips, counts; the truth's press level "
                  f"is {PRESSED:g} counts on the real glove, {PRESSED / 2:g} on the half-sensitive one). A level "
                  f"read off the rest spread (x a constant fitted to the real left hand) or the press range would have "
                  f"to agree with it within a few per cent (the -+5% rows above):", ""]
    lines += table(d.get("sensitivity", []), [("glove", "glove"), ("hand", "hand"), ("rest_spread", "rest spread"),
                                             ("rise_p99", "99th percentile rise"),
                                             ("press_from_spread", "press level from the spread")])
    lines += ["", f"Moving cells and `layouts suggest` (htdata/benchmarks/realglovecells.py; targets: flag precision "
                  f">= {t['moving_precision']:.2f} with no flag under {MOVING_STILL:g} counts; suggest >= "
                  f"{t['suggest_blocks']} blocks per hand, cell precision and recall >= {t['suggest_precision']:.2f})"
                  f":", ""]
    lines += cells_markdown(d)
    return lines + [""]
