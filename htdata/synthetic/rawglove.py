"""A realistic raw-count knit glove: two hands, 32x32, float16 counts, with the ground truth behind them.

The rest of the sample world is clean (values 0 at rest, no faults). Real
resistive knit gloves are not; this generator copies what a real two-hand
32x32 knitted glove does (issue 34; `htdata/synthetic/rawfacts.py` measures
the same numbers on it and on real recordings, tests/synthetic/test_rawglove_facts.py
compares them) and keeps the true press so that baselines, noise floors,
contact, moving cells and health can be scored against it:

copied:
- raw 10-bit counts stored as float16 (0.5-count steps above 512, 0.25
  below), value convention "direct", full scale 1023; saturation at SATURATE;
- rest ~557 (left) / ~566 (right) counts, per-cell offsets of a few counts
  with a tail of cells tens of counts higher, a per-cell gain (GAIN_STD);
- no fast noise to speak of (a cell mostly steps by 0 or half a count from
  frame to frame) but a slow rest wander of EVERY cell, taxel and gap alike
  (htdata/synthetic/restwander.py: a resting cell ranges ~5-7 counts over
  10 s and ~9 over 30 s, gaps about 2/3 of that), plus a slow drift
  (common-mode wander and a per-cell creep);
- the wiring of htdata/synthetic/rawlayout.py: fingers along raw columns,
  the palm touching every finger strip and the thumb (one connected sensor),
  column 31 without sensor that moves with the presses of its row
  (cross-talk: it swings up and down as a row's press changes);
- grips of htdata/synthetic/rawgrip.py: a grip presses a few tens of the
  ~690 live cells, most by 15-60 counts, a few by hundreds, so the mean over
  live cells moves by a few counts (<= 0.012 of full scale); cells beside a
  pressed patch that fall below rest instead of rising; clips that start
  mid-grasp (pressed from frame 0, released later) and knife clips whose
  working hand grips nearly the whole clip while the other hand steadies the
  food now and then;
- faults: a few dead cells (read their offset, never respond), stuck cells
  (constant, far above rest), cells saturating at rest, noisy cells;
- glove only (no camera), 30 fps.

not copied: the knit's hysteresis and creep under sustained load, the
nonlinear (roughly logarithmic) force response near saturation, temperature,
per-session recalibration of the ADC, frame drops and USB timing jitter.

The truth: `RawGloveClip.pressure[hand]` (T,32,32) is the press that produced
the counts in units of SPAN (before gain, wander, drift, faults, cross-talk;
0 on the cells that fall), and `truth_contact(hand)` is pressure >=
TRUTH_LEVEL (15 counts at gain 1: the real-glove measures' "pressed") on
live cells. `RawGloveClip.sinks[hand]` lists the cells that fall.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.glove.activity import MOVING_MIN_FULL_SCALE
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from htdata.synthetic.rawgrip import plan_hand, press_field
from htdata.synthetic.rawlayout import CROSSTALK_COL, GRID, LAYOUT_IDS, glove_layout, layout_doc, sensor_mask
from htdata.synthetic.rawlayout import FULL_SCALE as FULL_SCALE  # the glove's names, from one place
from htdata.synthetic.restwander import RestWander
from htdata.synthetic.tasks import stable_hash

SATURATE = 1020.0          # where cells saturate
REST = {"left": 557.0, "right": 566.0}   # a resting cell's median per hand, counts ...
REST_BASE = {"left": 556.5, "right": 563.5}  # ... over this base (the offsets' tail and the wander's bumps add)
OFFSET_STD = 1.3           # per-cell rest offset, counts ...
OFFSET_TAIL = (0.02, 10.0)  # ... and this share of cells sits higher by an exponential of this scale
GAIN_STD = 0.15            # per-cell gain, relative
SPAN = 460.0               # counts a full press adds at gain 1 (rest ~560 + 460 -> saturation)
NOISE_STD = 0.1            # fast noise, counts
LOUD_NOISE = 1.0           # std of the ~3% louder cells
NOISY_FAULT = 18.0         # std of the cells of fault class "noisy"
DRIFT_PER_MIN = 1.5        # per-cell creep, counts per minute (uniform in +-)
COMMON_DRIFT = 2.0         # common-mode wander amplitude, counts (period of minutes)
GAP_WANDER = 1.2           # cells without a sensor: walks x this, no bumps (htdata/synthetic/restwander.py)
CROSSTALK_GAIN = ((0.02, 0.12), (0.3, 1.0), 0.2)   # column 31 swings by this share of its row's press change
                                                    # over the last second: most rows little, this share a lot
TRUTH_LEVEL = 15.0 / SPAN  # true press at or above this is contact (15 counts at gain 1)
TOUCH_LEVEL = 5.0 / SPAN   # a sensor pressed this much is no longer quiet (5 counts): it moves
FPS = 30.0
COUNT_CHUNK = 2048         # frames per noise draw
FAULT_CLASSES = ("dead", "stuck", "saturating", "noisy")


DRAFT_FORGETS = ("thumb_distal",)


def draft_layout_doc(hand: str, forget: tuple[str, ...] = DRAFT_FORGETS) -> dict:
    """A first-draft layout of one hand: the `forget` blocks left out and no unused_cells, so the gaps and the
    forgotten sensor area are unmapped cells (the moving-cell rule is scored on it: htdata/benchmarks/rawglove.py)."""
    doc = layout_doc(hand)
    doc["blocks"] = [b for b in doc["blocks"] if b["name"] not in forget]
    doc["unused_cells"] = []
    doc["layout_id"] = f"{LAYOUT_IDS[hand]}_draft"
    return doc


def unmapped_truth(clip: "RawGloveClip", hand: str, unit: "GloveUnit", layout) -> dict[str, np.ndarray]:
    """(32,32) masks over the unmapped cells of `layout` in one clip: "pressed" (a sensor that responds and is
    pressed by more than the moving-cell rule's least move, MOVING_MIN_FULL_SCALE of full scale: a finding to
    make), "light" (pressed beyond quiet, TOUCH_LEVEL, but less than that: may be found or not), "ghost" (moves
    without a press: the cross-talk column, or a cell that falls beside a press) and "loud" (a louder noise than
    the glove's)."""
    free = np.asarray(layout.unmapped_mask, bool)
    broken = np.zeros(GRID, bool)
    for name in ("dead", "stuck", "saturating"):
        for r, c in unit.faults.cells[name]:
            broken[r, c] = True
    ghost = np.zeros(GRID, bool)
    ghost[:, unit.faults.crosstalk_cols] = True
    for r, c, _ in clip.sinks.get(hand, []):
        ghost[r, c] = True
    press = clip.pressure[hand].max(axis=0)
    moved = press * unit.gain * SPAN > MOVING_MIN_FULL_SCALE * FULL_SCALE      # counts the press added
    touched = free & ~broken & (press >= TOUCH_LEVEL)
    return {"pressed": touched & moved, "light": touched & ~moved,
            "ghost": free & ghost, "loud": free & (unit.noise >= LOUD_NOISE)}


@dataclass
class GloveFaults:
    """Raw-grid (row, col) cells of each fault class, and the cross-talk columns, of one hand."""
    cells: dict[str, list[tuple[int, int]]]
    crosstalk_cols: list[int]


@dataclass
class GloveUnit:
    """One physical hand of the glove: per-cell offset, gain, noise, creep, cross-talk and faults (fixed per glove)."""
    hand: str
    offset: np.ndarray      # (32,32) rest counts
    gain: np.ndarray        # (32,32)
    noise: np.ndarray       # (32,32) fast noise std, counts
    creep: np.ndarray       # (32,32) counts per minute
    wander: np.ndarray      # (32,32) scale of the slow rest wander (1 on sensors)
    crosstalk: np.ndarray   # (32,) gain of each row's press change onto the cross-talk column
    faults: GloveFaults

    @classmethod
    def make(cls, hand: str, seed: int) -> "GloveUnit":
        rng = np.random.default_rng([seed & 0xFFFFFFFF, stable_hash("rawglove-unit"), stable_hash(hand)])
        share, scale = OFFSET_TAIL
        offset = REST_BASE[hand] + rng.normal(0.0, OFFSET_STD, GRID)
        offset += np.where(rng.random(GRID) < share, rng.exponential(scale, GRID), 0.0)
        gain = np.clip(1.0 + rng.normal(0.0, GAIN_STD, GRID), 0.6, 1.5)
        noise = np.full(GRID, NOISE_STD)
        noise[rng.random(GRID) < 0.03] = LOUD_NOISE
        creep = rng.uniform(-DRIFT_PER_MIN, DRIFT_PER_MIN, GRID)
        layout = glove_layout(hand)
        wander = np.where(sensor_mask(), 1.0, GAP_WANDER)
        weak, strong, share = CROSSTALK_GAIN
        crosstalk = np.where(rng.random(GRID[0]) < share, rng.uniform(*strong, GRID[0]), rng.uniform(*weak, GRID[0]))
        crosstalk *= np.where(rng.random(GRID[0]) < 0.8, 1.0, -1.0)
        cells = [tuple(int(v) for v in c) for c in np.argwhere(layout.live_mask)]
        picks = rng.choice(len(cells), size=4 * 3, replace=False)
        faults = {name: [cells[int(i)] for i in picks[k * 3:(k + 1) * 3]] for k, name in enumerate(FAULT_CLASSES)}
        for r, c in faults["noisy"]:
            noise[r, c] = NOISY_FAULT
        return cls(hand, offset, gain, noise, creep, wander, crosstalk, GloveFaults(faults, [CROSSTALK_COL]))

    def counts(self, press: np.ndarray, fall: np.ndarray, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(T,32,32) press (>= 0) and fall (<= 0) in counts at times t_s (s since the glove was switched on) ->
        float16 counts."""
        signal = self.gain[None].astype(np.float32) * press + fall
        cross = self._crosstalk(signal)
        out = np.empty(press.shape, np.float16)
        wander = RestWander(self.wander, sensor_mask(), rng)   # each recording starts anywhere in its wander
        for a in range(0, len(press), COUNT_CHUNK):     # chunks: a 10-minute recording stays small in memory
            b = a + COUNT_CHUNK
            out[a:b] = self._counts(signal[a:b], cross[a:b], t_s[a:b], rng, wander)
        return out

    def _crosstalk(self, signal: np.ndarray) -> np.ndarray:
        """(T,32) what the cross-talk columns read over rest: each row's press minus its mean over the last
        second, times the row's cross-talk gain (a swing when the row's press changes, none while it holds)."""
        rows = signal.sum(axis=2, dtype=np.float64)                          # (T,32)
        n = max(1, int(round(FPS)))
        c = np.cumsum(np.concatenate([np.repeat(rows[:1], n, axis=0), rows]), axis=0)
        trailing = (c[n:] - c[:-n]) / n
        return (rows - trailing) * self.crosstalk[None]

    def _counts(self, signal: np.ndarray, cross: np.ndarray, t_s: np.ndarray, rng: np.random.Generator,
                wander: RestWander) -> np.ndarray:
        T = len(signal)
        dt = float(np.median(np.diff(t_s))) if T > 1 else 1.0 / FPS
        raw = wander.next(T, dt, rng)
        common = COMMON_DRIFT * np.sin(2 * np.pi * t_s / 240.0)                      # minutes-long wander
        drift = (common[:, None, None] + self.creep[None] * (t_s[:, None, None] / 60.0)).astype(np.float32)
        raw += drift
        raw += self.offset[None].astype(np.float32)
        raw += signal
        raw += rng.standard_normal((T, *GRID), dtype=np.float32) * self.noise[None].astype(np.float32)
        for col in self.faults.crosstalk_cols:
            raw[:, :, col] += cross.astype(np.float32)
        f = self.faults.cells
        for r, c in f["dead"]:
            raw[:, r, c] = self.offset[r, c]                                          # never responds
        for k, (r, c) in enumerate(f["stuck"]):
            raw[:, r, c] = 780.0 + 40 * k                                             # constant, far above rest
        for r, c in f["saturating"]:
            raw[:, r, c] = SATURATE                                                   # saturated at rest
        return np.clip(raw, 0.0, SATURATE, out=raw)


@dataclass
class RawGloveClip:
    """One glove-only clip: counts and true press per hand, timestamps, where it starts, the cells that fall."""
    name: str
    task: str
    start: str                     # "rest" or "mid_grasp"
    fps: float
    t0_s: float                    # seconds since the glove was switched on (drift clock)
    counts: dict[str, np.ndarray]  # hand -> (T,32,32) float16
    pressure: dict[str, np.ndarray] = field(default_factory=dict)   # hand -> (T,32,32) float32 truth
    sinks: dict[str, list[tuple[int, int, float]]] = field(default_factory=dict)   # hand -> (row, col, counts)
    working: str = "right"         # the hand that does the task (the other steadies)

    @property
    def n_frames(self) -> int:
        return len(next(iter(self.counts.values())))

    def truth_contact(self, hand: str) -> np.ndarray:
        """(T, L) bool: live taxels whose true press is >= TRUTH_LEVEL."""
        return self.pressure[hand][:, glove_layout(hand).live_mask] >= TRUTH_LEVEL


def make_clip(name: str, task: str, n_frames: int, start: str, seed: int, units: dict[str, GloveUnit],
              t0_s: float = 0.0, fps: float = FPS) -> RawGloveClip:
    """A glove-only clip of `units`' hands; the right hand (or the only one) works, the other steadies.
    "mid_grasp" clips begin with the working hand already gripping (pressed from frame 0, released later);
    tasks: htdata/synthetic/rawgrip.py TASKS."""
    if start not in ("rest", "mid_grasp"):
        raise ValueError(f"start must be 'rest' or 'mid_grasp', got {start!r}")
    times = np.arange(n_frames, dtype=np.float64) / fps
    working = "right" if "right" in units else next(iter(units))
    rng = np.random.default_rng([seed & 0xFFFFFFFF, stable_hash("rawglove-noise"), stable_hash(name)])
    pressure, counts, sinks = {}, {}, {}
    for hand, unit in units.items():
        plan = plan_hand(task, "working" if hand == working else "support", start, n_frames / fps, seed, hand)
        press, fall = press_field(plan, times)
        pressure[hand] = press / np.float32(SPAN)
        sinks[hand] = list(plan.sinks)
        counts[hand] = unit.counts(press, fall, t0_s + times, rng)
    return RawGloveClip(name, task, start, fps, t0_s, counts, pressure, sinks, working)


# The corpus clips: (task, frames, start). Glove only, 180..450 frames (the real clips run 135-1000): knife clips
# whose working hand grips nearly all along (one from frame 0) while the other steadies the food, pouring clips
# (one starting mid-grasp).
CLIPS = (("slice", 450, "rest"), ("pour", 240, "mid_grasp"), ("peel", 300, "rest"),
         ("slice", 360, "mid_grasp"), ("pour", 180, "rest"))


def corpus_clips(seed: int = 0) -> tuple[dict[str, GloveUnit], list[RawGloveClip]]:
    """The glove (both hands) and the clips `write_rawglove` writes; each clip later on the drift clock."""
    units = {h: GloveUnit.make(h, seed) for h in ("left", "right")}
    clips, t0 = [], 0.0
    for k, (task, n, start) in enumerate(CLIPS):
        clips.append(make_clip(f"rawknit_{k:02d}_{task}_{start}", task, n, start,
                               stable_hash(seed, "rawglove", k) & 0x7FFFFFFF, units, t0_s=t0))
        t0 += n / FPS + 15.0          # a pause between recordings: the rest level keeps drifting
    return units, clips


def write_rawglove(out: Path, seed: int = 0) -> dict:
    """Write OUT/layouts/*.json, OUT/<clip>/ (htdata-native, glove only, float16), OUT/truth.json and
    OUT/layouts/<layout>.calibration.npz (the glove's per-taxel offset and gain: `taxel_calibration`).

    Ingest: `htdata ingest --source native=OUT --layouts OUT/layouts ...`.
    truth.json names each clip's start ("rest" / "mid_grasp"), its working hand and the cells that fall beside
    a press (per hand: row, col, counts), and each hand's fault cells and cross-talk columns.
    """

    out = Path(out)
    (out / "layouts").mkdir(parents=True, exist_ok=True)
    for hand, lid in LAYOUT_IDS.items():
        (out / "layouts" / f"{lid}.json").write_text(json.dumps(layout_doc(hand), indent=1))
    units, clips = corpus_clips(seed)
    truth = {"truth_level": TRUTH_LEVEL, "clips": {},
             "faults": {h: {"cells": u.faults.cells, "crosstalk_cols": u.faults.crosstalk_cols}
                        for h, u in units.items()}}
    for clip in clips:
        start_ns = int(1e12 + clip.t0_s * 1e9)
        ts = start_ns + np.round(np.arange(clip.n_frames) / clip.fps * 1e9).astype(np.int64)
        hands = {h: NativeHand(LAYOUT_IDS[h], clip.counts[h], ts, dtype="float16") for h in clip.counts}
        write_native_recording(out / clip.name, NativeRecording(
            task=clip.task, scene="lab_bench", video_frames=iter(()), video_timestamps_ns=np.zeros(0, np.int64),
            hands=hands, operator="synthetic", notes="htdata sample raw-count glove", video_storage="none",
            extra={"seed": seed, "start": clip.start}))
        truth["clips"][clip.name] = {"task": clip.task, "start": clip.start, "frames": clip.n_frames,
                                     "working_hand": clip.working,
                                     "falling_cells": {h: [[r, c, round(d, 2)] for r, c, d in s]
                                                       for h, s in clip.sinks.items()}}
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    # the glove's per-taxel offsets and gains, as a calibration measured once (pipeline key taxel_calibration)
    for hand, unit in units.items():
        np.savez(out / "layouts" / f"{LAYOUT_IDS[hand]}.calibration.npz", offset=unit.offset.astype(np.float32),
                 gain=(1.0 / unit.gain).astype(np.float32))   # the multiplier that evens out sensitivity
    return {"clips": len(clips), "frames": sum(c.n_frames for c in clips)}
