"""A realistic raw-count knit glove: two hands, 32x32, float16 counts, with the ground truth behind them.

The rest of the sample world is clean (values 0 at rest, no faults). Real
resistive knit gloves are not; this generator copies the properties that
break a clean-world pipeline (measured on a two-hand 32x32 knit glove,
issue 19) and keeps the true pressure so that baselines, noise floors,
contact and health can be scored against it:

copied:
- raw 10-bit counts stored as float16 (integers, exact in half precision),
  value convention "direct", full scale 1023, quantisation step 1 count;
- rest level ~550 with a per-taxel offset (std OFFSET_STD counts) and a
  per-taxel gain (std GAIN_STD relative), contact up to the ADC top where
  cells saturate (SATURATE counts);
- per-taxel sensor noise of about one count (so about a third of the taxels
  have zero robust spread, MAD, over a 10-frame window), a few louder;
- slow drift of the rest level (a common-mode wander plus a per-taxel
  linear creep, DRIFT_PER_MIN counts/minute at most);
- slow rest wander of EVERY cell, taxel and gap alike (issue 27): an
  Ornstein-Uhlenbeck walk of stationary std WANDER_STD counts and time
  constant WANDER_TAU_S, so a resting cell's range over a 200-600 frame clip
  is a median ~5-7 counts (the real glove: median 5, p90 6-7) while its
  frame-to-frame noise stays about a count;
- faults: a few dead cells (read their offset, never respond), stuck cells
  (constant, far above rest), cells saturating at rest, noisy cells, and
  cross-talk lines (a raw row that ghosts a share of the strongest press in
  that row onto every cell of the row);
- glove only (no camera), 30 fps, and clips that start mid-grasp (the hand
  already holding the object in frame 0) as well as clips that start at rest;
- cells outside every block that still read counts (the grid's gaps).

not copied: the knit's hysteresis and creep under sustained load, the
nonlinear (roughly logarithmic) force response near saturation, temperature,
per-session recalibration of the ADC, frame drops and USB timing jitter,
fingers whose blocks run along raw columns (issue 19 item 1: the layout here
keeps every block along raw rows).

The truth: `RawGloveClip.pressure[hand]` (T,32,32) in [0,1] is the press
that produced the counts (before gain, noise, drift, faults, cross-talk),
and `truth_contact(hand)` is pressure >= TRUTH_LEVEL on live cells.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.glove.layouts import parse_layout
from htdata.synthetic.formats import NativeHand, NativeRecording, write_native_recording
from htdata.synthetic.tasks import stable_hash
from htdata.synthetic.world import EpisodeSpec, World

GRID = (32, 32)
FULL_SCALE = 1023.0        # layout value.max: full-scale raw (10-bit ADC)
SATURATE = 1022.0          # where cells saturate
REST = 550.0
OFFSET_STD = 25.0          # per-taxel rest offset, counts
GAIN_STD = 0.15            # per-taxel gain, relative
SPAN = 470.0               # counts a full press adds at gain 1 (rest 550 + 470 -> saturation)
NOISE_COUNTS = (0.4, 1.2) # per-taxel noise std drawn uniformly in this range, counts
LOUD_NOISE = 3.0           # std of the ~5% louder taxels
DRIFT_PER_MIN = 6.0        # per-taxel creep, counts per minute (uniform in +-)
COMMON_DRIFT = 4.0         # common-mode wander amplitude, counts (period of minutes)
WANDER_STD = 2.0           # per-cell slow rest wander: stationary std, counts (Ornstein-Uhlenbeck)
WANDER_TAU_S = 4.0         # ... and its time constant, seconds
CROSSTALK_SHARE = 0.12     # a ghost row carries this share of the row's strongest press
TRUTH_LEVEL = 0.05         # true pressure at or above this is contact (~23 counts at gain 1)
FPS = 30.0
COUNT_CHUNK = 2048           # frames per noise draw
LAYOUT_IDS = {"left": "rawknit_left_32x32", "right": "rawknit_right_32x32"}
FAULT_CLASSES = ("dead", "stuck", "saturating", "noisy")

# Fingers run along raw rows (distal rows 0-3, middle 4-7, proximal 8-11); gaps between blocks are
# cells the layout leaves out (they read counts like any other cell).
_FINGERS = (("little", 1), ("ring", 7), ("middle", 13), ("index", 19))
_SEGMENTS = (("distal", (0, 3)), ("middle", (4, 7)), ("proximal", (8, 11)))


def layout_doc(hand: str) -> dict:
    """The layout document of one hand of the raw-count glove."""
    blocks = []
    for finger, c0 in _FINGERS:
        for seg, rows in _SEGMENTS:
            blocks.append({"name": f"{finger}_{seg}", "place": f"{finger}.{seg}", "rows": list(rows),
                           "cols": [c0, c0 + 3]})
    blocks += [
        {"name": "thumb_distal", "place": "thumb.distal", "rows": [4, 7], "cols": [26, 29]},
        {"name": "thumb_proximal", "place": "thumb.proximal", "rows": [8, 12], "cols": [26, 29]},
        {"name": "palm_upper_ulnar", "place": "palm.upper_ulnar", "rows": [14, 20], "cols": [1, 10]},
        {"name": "palm_upper_radial", "place": "palm.upper_radial", "rows": [14, 20], "cols": [12, 23]},
        {"name": "palm_lower_ulnar", "place": "palm.lower_ulnar", "rows": [22, 30], "cols": [1, 10]},
        {"name": "palm_lower_radial", "place": "palm.lower_radial", "rows": [22, 30], "cols": [12, 23]},
    ]
    inside = np.zeros(GRID, bool)
    for b in blocks:
        b.update({"flip_x": False, "flip_y": False})
        inside[b["rows"][0]:b["rows"][1] + 1, b["cols"][0]:b["cols"][1] + 1] = True
    # The gaps between blocks are knit too and read counts (cross-talk lines run through them): listed
    # as deliberately unused, so a moving cell outside the blocks is a finding, not the gaps' noise.
    unused = [[int(r), int(c)] for r, c in np.argwhere(~inside)]
    return {"layout_id": LAYOUT_IDS[hand], "hand": hand, "grid": list(GRID),
            "value": {"convention": "direct", "max": FULL_SCALE, "step": 1},
            "blocks": blocks, "dead_cells": [], "bend_cells": [], "unused_cells": unused,
            "source": "htdata sample raw-count glove (htdata/synthetic/rawglove.py): synthetic",
            "notes": "10-bit counts, rest ~550 with per-taxel offsets and gains, full scale 1023, step 1 count."}


def glove_layout(hand: str):
    return parse_layout(layout_doc(hand), f"<{LAYOUT_IDS[hand]}>")


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
    pressed >= TRUTH_LEVEL), "ghost" (on a cross-talk row) and "loud" (a louder noise than the glove's)."""
    free = np.asarray(layout.unmapped_mask, bool)
    broken = np.zeros(GRID, bool)
    for name in ("dead", "stuck", "saturating"):
        for r, c in unit.faults.cells[name]:
            broken[r, c] = True
    ghost = np.zeros(GRID, bool)
    ghost[unit.faults.crosstalk_rows, :] = True
    return {"pressed": free & ~broken & (clip.pressure[hand].max(axis=0) >= TRUTH_LEVEL),
            "ghost": free & ghost, "loud": free & (unit.noise >= LOUD_NOISE)}


@dataclass
class GloveFaults:
    """Raw-grid (row, col) cells of each fault class, and the cross-talk rows, of one hand."""
    cells: dict[str, list[tuple[int, int]]]
    crosstalk_rows: list[int]


@dataclass
class GloveUnit:
    """One physical hand of the glove: per-cell offset, gain, noise, creep and faults (fixed per glove)."""
    hand: str
    offset: np.ndarray      # (32,32) rest counts
    gain: np.ndarray        # (32,32)
    noise: np.ndarray       # (32,32) std, counts
    creep: np.ndarray       # (32,32) counts per minute
    faults: GloveFaults

    @classmethod
    def make(cls, hand: str, seed: int) -> "GloveUnit":
        rng = np.random.default_rng([seed & 0xFFFFFFFF, stable_hash("rawglove-unit"), stable_hash(hand)])
        offset = REST + rng.normal(0.0, OFFSET_STD, GRID)
        gain = np.clip(1.0 + rng.normal(0.0, GAIN_STD, GRID), 0.5, 1.6)
        noise = rng.uniform(*NOISE_COUNTS, GRID)
        noise[rng.random(GRID) < 0.05] = LOUD_NOISE
        creep = rng.uniform(-DRIFT_PER_MIN, DRIFT_PER_MIN, GRID)
        live = glove_layout(hand).live_mask
        cells = [tuple(int(v) for v in c) for c in np.argwhere(live)]
        picks = rng.choice(len(cells), size=4 * 3, replace=False)
        faults = {name: [cells[int(i)] for i in picks[k * 3:(k + 1) * 3]] for k, name in enumerate(FAULT_CLASSES)}
        for r, c in faults["noisy"]:
            noise[r, c] = 18.0
        ghost = sorted(int(r) for r in rng.choice([1, 5, 9, 16, 25], size=2, replace=False))
        return cls(hand, offset, gain, noise, creep, GloveFaults(faults, ghost))

    def counts(self, pressure: np.ndarray, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(T,32,32) true pressure in [0,1] at times t_s (s since the glove was switched on) -> float16 counts."""
        out = np.empty(pressure.shape, np.float16)
        wander = rng.normal(0.0, WANDER_STD, GRID)          # each recording starts anywhere in its wander
        for a in range(0, len(pressure), COUNT_CHUNK):     # chunks: a 10-minute recording stays small in memory
            out[a:a + COUNT_CHUNK], wander = self._counts(pressure[a:a + COUNT_CHUNK], t_s[a:a + COUNT_CHUNK],
                                                          rng, wander)
        return out

    @staticmethod
    def _wander(T: int, dt: float, last: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(T,32,32) Ornstein-Uhlenbeck rest wander continuing from the previous frame's `last`."""
        from scipy.signal import lfilter

        a = float(np.exp(-dt / WANDER_TAU_S))
        steps = rng.normal(0.0, WANDER_STD * np.sqrt(1.0 - a * a), (T, *GRID))
        return lfilter([1.0], [1.0, -a], steps, axis=0, zi=(a * last)[None])[0]

    def _counts(self, pressure: np.ndarray, t_s: np.ndarray, rng: np.random.Generator,
                wander: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        T = len(pressure)
        common = COMMON_DRIFT * np.sin(2 * np.pi * t_s / 240.0)                      # minutes-long wander
        dt = float(np.median(np.diff(t_s))) if T > 1 else 1.0 / FPS
        walk = self._wander(T, dt, wander, rng)
        drift = common[:, None, None] + self.creep[None] * (t_s[:, None, None] / 60.0) + walk
        signal = self.gain[None] * SPAN * pressure
        rows = self.faults.crosstalk_rows
        if rows:   # ghosting: the row's strongest press leaks onto every cell of the row
            signal[:, rows, :] += CROSSTALK_SHARE * signal[:, rows, :].max(axis=2, keepdims=True)
        raw = self.offset[None] + drift + signal + rng.normal(0.0, 1.0, (T, *GRID)) * self.noise[None]
        f = self.faults.cells
        for r, c in f["dead"]:
            raw[:, r, c] = self.offset[r, c]                                          # never responds
        for k, (r, c) in enumerate(f["stuck"]):
            raw[:, r, c] = 780.0 + 40 * k                                             # constant, far above rest
        for r, c in f["saturating"]:
            raw[:, r, c] = SATURATE                                                   # saturated at rest
        return np.clip(np.round(raw), 0.0, SATURATE), walk[-1]


@dataclass
class RawGloveClip:
    """One glove-only clip: counts and true pressure per hand, timestamps, where it starts."""
    name: str
    task: str
    start: str                     # "rest" or "mid_grasp"
    fps: float
    t0_s: float                    # seconds since the glove was switched on (drift clock)
    counts: dict[str, np.ndarray]  # hand -> (T,32,32) float16
    pressure: dict[str, np.ndarray] = field(default_factory=dict)   # hand -> (T,32,32) float32 truth

    @property
    def n_frames(self) -> int:
        return len(next(iter(self.counts.values())))

    def truth_contact(self, hand: str) -> np.ndarray:
        """(T, L) bool: live taxels whose true pressure is >= TRUTH_LEVEL."""
        return self.pressure[hand][:, glove_layout(hand).live_mask] >= TRUTH_LEVEL


def make_clip(name: str, task: str, n_frames: int, start: str, seed: int, units: dict[str, GloveUnit],
              t0_s: float = 0.0, fps: float = FPS) -> RawGloveClip:
    """A two-hand glove-only clip; "mid_grasp" clips begin with the dominant hand already gripping."""
    if start not in ("rest", "mid_grasp"):
        raise ValueError(f"start must be 'rest' or 'mid_grasp', got {start!r}")
    # the world runs an episode whose contact spans ~25%..70%; a mid-grasp clip starts inside it
    full = n_frames if start == "rest" else int(round(n_frames / 0.62))
    spec = EpisodeSpec(task, "lab_bench", seed, full, fps, ("left", "right"))
    world = World(spec)
    times = spec.frame_times()
    first = 0
    if start == "mid_grasp":
        force = world.state(world.dominant, times).force
        first = int(np.flatnonzero(force >= 0.6 * force.max())[0])
    times = times[first:first + n_frames]
    rng = np.random.default_rng([seed & 0xFFFFFFFF, stable_hash("rawglove-noise"), stable_hash(name)])
    pressure, counts = {}, {}
    for hand, unit in units.items():
        p = world.contact_grids(glove_layout(hand), hand, times, fill=0.0).astype(np.float32)
        pressure[hand] = p
        counts[hand] = unit.counts(p, t0_s + times - times[0], rng)
    return RawGloveClip(name, task, start, fps, t0_s, counts, pressure)


# The corpus clips: (task, frames, start). Glove only, 200..600 frames (the real clips run 200-2000).
CLIPS = (("pinch_pick", 240, "rest"), ("power_grasp", 300, "mid_grasp"),
         ("palm_push", 210, "rest"), ("power_grasp", 360, "rest"), ("pinch_pick", 270, "mid_grasp"))


def corpus_clips(seed: int = 0) -> tuple[dict[str, GloveUnit], list[RawGloveClip]]:
    """The glove (both hands) and the clips `write_rawglove` writes; each clip later on the drift clock."""
    units = {h: GloveUnit.make(h, seed) for h in ("left", "right")}
    clips, t0 = [], 0.0
    for k, (task, n, start) in enumerate(CLIPS):
        clips.append(make_clip(f"rawknit_{k:02d}_{task}_{start}", task, n, start,
                               stable_hash(seed, "rawglove", k) & 0x7FFFFFFF, units, t0_s=t0))
        t0 += n / FPS + 45.0          # a pause between recordings: the rest level keeps drifting
    return units, clips


def write_rawglove(out: Path, seed: int = 0) -> dict:
    """Write OUT/layouts/*.json, OUT/<clip>/ (htdata-native, glove only, float16), OUT/truth.json and
    OUT/layouts/<layout>.calibration.npz (the glove's per-taxel offset and gain: `taxel_calibration`).

    Ingest: `htdata ingest --source native=OUT --layouts OUT/layouts ...`.
    truth.json names each clip's start ("rest" / "mid_grasp") and each hand's fault cells and ghost rows.
    """

    out = Path(out)
    (out / "layouts").mkdir(parents=True, exist_ok=True)
    for hand, lid in LAYOUT_IDS.items():
        (out / "layouts" / f"{lid}.json").write_text(json.dumps(layout_doc(hand), indent=1))
    units, clips = corpus_clips(seed)
    truth = {"truth_level": TRUTH_LEVEL, "clips": {},
             "faults": {h: {"cells": u.faults.cells, "crosstalk_rows": u.faults.crosstalk_rows}
                        for h, u in units.items()}}
    for clip in clips:
        start_ns = int(1e12 + clip.t0_s * 1e9)
        ts = start_ns + np.round(np.arange(clip.n_frames) / clip.fps * 1e9).astype(np.int64)
        hands = {h: NativeHand(LAYOUT_IDS[h], clip.counts[h], ts, dtype="float16") for h in clip.counts}
        write_native_recording(out / clip.name, NativeRecording(
            task=clip.task, scene="lab_bench", video_frames=iter(()), video_timestamps_ns=np.zeros(0, np.int64),
            hands=hands, operator="synthetic", notes="htdata sample raw-count glove", video_storage="none",
            extra={"seed": seed, "start": clip.start}))
        truth["clips"][clip.name] = {"task": clip.task, "start": clip.start, "frames": clip.n_frames}
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    # the glove's per-taxel offsets and gains, as a calibration measured once (pipeline key taxel_calibration)
    for hand, unit in units.items():
        np.savez(out / "layouts" / f"{LAYOUT_IDS[hand]}.calibration.npz", offset=unit.offset.astype(np.float32),
                 gain=(1.0 / unit.gain).astype(np.float32))   # the multiplier that evens out sensitivity
    return {"clips": len(clips), "frames": sum(c.n_frames for c in clips)}
