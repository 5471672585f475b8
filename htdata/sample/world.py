"""A deterministic synthetic "world" for the sample corpus.

One hidden state per episode (task, object, hand trajectory, grip force,
finger closure) drives BOTH what a glove would feel (`contact_grid`) and
what the egocentric camera sees (`render_frame`), so that an RGB frame
predicts the contact map: fingers close when force rises, the object sits
between thumb and index for a pinch, under the palm for a palm push.

Everything is a pure function of (task, scene, seed) and continuous time in
seconds, so a 100 Hz tactile stream and a 30 Hz video of the same episode
come from the same world. Stable hashes (crc32), never Python's salted hash().
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Iterator

import cv2
import numpy as np

HANDS = ("left", "right")
FINGERS = ("thumb", "index", "middle", "ring", "little")
GROUPS = FINGERS + ("palm",)
# Canonical place names (docs/DESIGN.md, "Canonical hand frame").
PLACE_NAMES: tuple[str, ...] = (
    "thumb.distal", "thumb.proximal",
    *(f"{f}.{p}" for f in FINGERS[1:] for p in ("distal", "middle", "proximal")),
    "palm.upper_ulnar", "palm.upper_radial", "palm.lower_ulnar", "palm.lower_radial",
)

PHASE_APPROACH, PHASE_CONTACT, PHASE_RELEASE = 0, 1, 2


def stable_hash(*parts: Any) -> int:
    """32-bit hash stable across processes (Python's hash() is salted)."""
    return zlib.crc32("\x1f".join(str(p) for p in parts).encode())


def _expand(spec: dict[str, float]) -> dict[str, float]:
    """Expand group keys ("palm", "index") into their places; places win over groups."""
    out: dict[str, float] = {}
    for key, value in spec.items():
        if key in GROUPS:
            for place in PLACE_NAMES:
                if place.split(".")[0] == key:
                    out.setdefault(place, value)
    for key, value in spec.items():
        if key in GROUPS:
            continue
        if key not in PLACE_NAMES:
            raise ValueError(f"unknown place {key!r}; known: {', '.join(PLACE_NAMES)}")
        out[key] = value
    return {k: v for k, v in out.items() if v > 0}


@dataclass(frozen=True)
class TaskProfile:
    """How a task touches: contact intensity per canonical place, finger closure, object."""

    name: str
    contact: dict[str, float]       # place -> intensity in (0,1], dominant hand
    support: dict[str, float]       # place -> intensity, the other hand (may be empty)
    closure: tuple[float, ...]      # target closure per finger (thumb..little), 0 open, 1 fist
    anchor: str                     # which hand point meets the object (see _anchor_point)
    shape: str                      # object drawing
    colour: tuple[int, int, int]    # object RGB
    carry: bool                     # object is lifted during contact


def _task(name, contact, support, closure, anchor, shape, colour, carry) -> TaskProfile:
    return TaskProfile(name, _expand(contact), _expand(support), tuple(closure), anchor,
                       shape, colour, carry)


TASKS: dict[str, TaskProfile] = {t.name: t for t in (
    _task("pinch_pick", {"thumb.distal": 1.0, "index.distal": 1.0},
          {}, (0.55, 0.5, 0.3, 0.3, 0.3), "pinch", "sphere", (215, 30, 40), True),
    _task("power_grasp", {"palm": 0.8, "thumb": 0.9, "index": 1.0, "middle": 1.0,
                          "ring": 0.9, "little": 0.75},
          {"palm": 0.4}, (0.85, 0.9, 0.9, 0.9, 0.9), "fist", "bottle", (30, 80, 220), True),
    _task("press_button", {"index.distal": 1.0},
          {"palm.lower_ulnar": 0.3, "palm.lower_radial": 0.3},
          (0.7, 0.1, 0.85, 0.85, 0.85), "index_tip", "button", (240, 205, 20), False),
    _task("tripod_grasp", {"thumb.distal": 1.0, "index.distal": 0.9, "middle.distal": 0.8},
          {}, (0.55, 0.5, 0.5, 0.35, 0.35), "tripod", "cap", (40, 175, 60), True),
    _task("lateral_key_turn", {"thumb.distal": 1.0, "index.middle": 0.8, "index.proximal": 0.6},
          {"palm": 0.3, "index.distal": 0.3, "middle.distal": 0.3},
          (0.45, 0.9, 0.9, 0.9, 0.9), "lateral", "key", (240, 135, 20), False),
    _task("palm_push", {"palm": 1.0},
          {}, (0.0, 0.05, 0.05, 0.05, 0.05), "palm", "box", (140, 60, 180), False),
    _task("hook_carry", {"index.middle": 0.9, "index.proximal": 0.7, "middle.middle": 1.0,
                         "middle.proximal": 0.8, "ring.middle": 0.9, "ring.proximal": 0.7,
                         "little.middle": 0.6},
          {}, (0.0, 0.75, 0.75, 0.75, 0.75), "hook", "bag", (20, 185, 200), True),
)}

# Scene styles, chosen by keyword in the scene name (OpenTouch "home_kitchen_p1",
# TouchAnything "Home", native "lab_bench").
SCENE_STYLES: dict[str, dict[str, Any]] = {
    "kitchen": {"keywords": ("kitchen", "home"), "wall": (196, 170, 130), "table": (150, 105, 65),
                "texture": "wood"},
    "office": {"keywords": ("office", "desk"), "wall": (175, 185, 200), "table": (120, 120, 125),
               "texture": "grid"},
    "grocery": {"keywords": ("grocery", "retail", "store", "target"), "wall": (235, 235, 228),
                "table": (200, 200, 195), "texture": "shelves"},
    "workbench": {"keywords": ("workbench", "garage", "outdoor"), "wall": (90, 110, 95),
                  "table": (70, 75, 70), "texture": "noise"},
    "lab": {"keywords": ("lab", "native", "bench"), "wall": (215, 220, 225), "table": (60, 90, 120),
            "texture": "grid"},
}


def scene_style(scene: str) -> str:
    """Style name for a scene name (keyword match, case-insensitive)."""
    low = scene.lower()
    for style, spec in SCENE_STYLES.items():
        if any(k in low for k in spec["keywords"]):
            return style
    known = sorted(k for s in SCENE_STYLES.values() for k in s["keywords"])
    raise ValueError(f"scene {scene!r} matches no style; its name must contain one of {known}")


@dataclass
class EpisodeSpec:
    """One synthetic episode: what happens (task, scene), its seed and timing."""

    task: str
    scene: str
    seed: int
    n_frames: int
    fps: float = 30.0
    hands: tuple[str, ...] = ("right",)

    def validate(self) -> "EpisodeSpec":
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; known: {', '.join(TASKS)}")
        scene_style(self.scene)
        if int(self.n_frames) < 1:
            raise ValueError(f"episode {self.task}/{self.scene}/{self.seed}: n_frames must be >= 1")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise ValueError(f"episode {self.task}/{self.scene}/{self.seed}: fps must be > 0")
        if not self.hands or any(h not in HANDS for h in self.hands) or \
                len(set(self.hands)) != len(self.hands):
            raise ValueError(f"hands must be a non-empty subset of {HANDS}, got {self.hands}")
        self.hands = tuple(h for h in HANDS if h in self.hands)
        return self

    @property
    def duration_s(self) -> float:
        return self.n_frames / self.fps

    def frame_times(self, fps: float | None = None) -> np.ndarray:
        """Sample times (s) over the episode at `fps` (default: the video fps)."""
        rate = self.fps if fps is None else float(fps)
        n = max(1, int(round(self.duration_s * rate)))
        return np.arange(n, dtype=np.float64) / rate


@dataclass
class HandState:
    """Hidden state of one hand at T times (every array has leading dim T)."""

    task: str
    hand: str
    role: str                 # "dominant" (task profile) or "support"
    t: np.ndarray             # (T,) seconds
    phase: np.ndarray         # (T,) int8: 0 approach, 1 contact, 2 release
    force: np.ndarray         # (T,) float32 in [0,1]; exactly 0 outside contact
    closure: np.ndarray       # (T,5) float32 in [0,1], thumb..little
    hand_xy: np.ndarray       # (T,2) float32 world units (1 = image short side)
    jitter_key: int           # seeds the blob-centre jitter per glove block

    def __len__(self) -> int:
        return len(self.t)

    def frame(self, i: int) -> "HandState":
        s = slice(i, i + 1)
        return HandState(self.task, self.hand, self.role, self.t[s], self.phase[s], self.force[s],
                         self.closure[s], self.hand_xy[s], self.jitter_key)

    @property
    def profile(self) -> dict[str, float]:
        task = TASKS[self.task]
        return task.contact if self.role == "dominant" else task.support


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass
class _HandPlan:
    """Per-hand random parameters drawn once per episode."""

    a: float                  # contact starts (fraction of the episode)
    b: float                  # contact ends
    ramp: float               # force ramp width (fraction)
    peak: float               # peak force
    start_xy: np.ndarray      # where the hand enters
    target_xy: np.ndarray     # palm centre while touching
    tremor_f: np.ndarray      # (3,) Hz
    tremor_p: np.ndarray      # (3,) phases
    jitter_key: int


class World:
    """The hidden world of one episode; evaluate it at any time, render any view."""

    def __init__(self, spec: EpisodeSpec):
        self.spec = spec.validate()
        self.task = TASKS[spec.task]
        self.style = scene_style(spec.scene)
        rng = np.random.default_rng([spec.seed & 0xFFFFFFFF, stable_hash(spec.task),
                                     stable_hash(spec.scene)])
        self.object_xy = np.array([rng.uniform(0.38, 0.62), rng.uniform(0.40, 0.55)])
        self.object_scale = float(rng.uniform(0.85, 1.15))
        jitter = rng.integers(-18, 19, size=3)
        self.object_rgb = tuple(int(np.clip(c + j, 0, 255)) for c, j in zip(self.task.colour, jitter))
        self.dominant = "right" if "right" in spec.hands else "left"
        self.plans = {h: self._plan(rng, h) for h in spec.hands}

    # ---- hidden state -------------------------------------------------------
    def _plan(self, rng: np.random.Generator, hand: str) -> _HandPlan:
        a = rng.uniform(0.15, 0.30)
        b = a + rng.uniform(0.40, 0.55)
        side = 1.0 if hand == "right" else -1.0
        if hand == self.dominant:
            closure = np.array(self.task.closure)
            offset = _anchor_point(self.task.anchor, closure, hand)
            target = self.object_xy - offset
        else:  # support hand steadies things beside the object
            target = self.object_xy + np.array([side * 0.30, 0.18])
        return _HandPlan(
            a=a, b=min(b, 0.9), ramp=rng.uniform(0.05, 0.10), peak=rng.uniform(0.6, 1.0),
            start_xy=np.array([0.5 + side * rng.uniform(0.15, 0.3), rng.uniform(1.05, 1.2)]),
            target_xy=target, tremor_f=rng.uniform(6.0, 12.0, 3),
            tremor_p=rng.uniform(0, 2 * np.pi, 3), jitter_key=int(rng.integers(0, 2**31 - 1)))

    def state(self, hand: str, times_s: np.ndarray | None = None) -> HandState:
        """Hidden state of `hand` at `times_s` (default: the video frame times)."""
        if hand not in self.plans:
            raise ValueError(f"episode {self.spec.task}/{self.spec.scene}/{self.spec.seed} has no "
                             f"{hand} hand (hands: {self.spec.hands})")
        t = self.spec.frame_times() if times_s is None else np.asarray(times_s, dtype=np.float64)
        p = self.plans[hand]
        u = (t + 0.5 / self.spec.fps) / self.spec.duration_s   # frame centres: T=1 is mid-contact
        phase = np.where(u < p.a, PHASE_APPROACH, np.where(u < p.b, PHASE_CONTACT, PHASE_RELEASE))
        envelope = _smoothstep((u - p.a) / p.ramp) * _smoothstep((p.b - u) / p.ramp)
        envelope = np.where(phase == PHASE_CONTACT, envelope, 0.0)
        tremor = sum(np.sin(2 * np.pi * f * t + ph) for f, ph in zip(p.tremor_f, p.tremor_p)) / 3
        slow = 0.08 * np.sin(2 * np.pi * 0.7 * t + p.tremor_p[0])  # grip force wanders
        force = np.clip(p.peak * envelope * (1.0 + slow + 0.04 * tremor), 0.0, 1.0)
        # Fingers pre-shape a little before contact and open a little after it.
        pre = 0.08
        shape = _smoothstep((u - p.a + pre) / (p.ramp + pre)) * _smoothstep((p.b + pre - u) / (p.ramp + pre))
        role = "dominant" if hand == self.dominant else "support"
        target_closure = np.array(self.task.closure if role == "dominant" else (0.3,) * 5)
        closure = np.clip(shape[:, None] * target_closure[None, :], 0.0, 1.0)
        # Reach: in during approach, out during release, tremor on top.
        reach = _smoothstep(u / max(p.a, 1e-6)) * _smoothstep((1.0 - u) / max(1.0 - p.b, 1e-6))
        xy = p.start_xy[None, :] + reach[:, None] * (p.target_xy - p.start_xy)[None, :]
        if self.task.carry and role == "dominant":
            lift = np.sin(np.pi * np.clip((u - p.a) / (p.b - p.a), 0, 1)) * 0.06
            xy[:, 1] -= np.where(phase == PHASE_CONTACT, lift, 0.0)
        xy += 0.003 * np.stack([np.sin(2 * np.pi * p.tremor_f[1] * t + p.tremor_p[2]),
                                np.cos(2 * np.pi * p.tremor_f[2] * t + p.tremor_p[1])], axis=1)
        return HandState(self.spec.task, hand, role, t, phase.astype(np.int8),
                         force.astype(np.float32), closure.astype(np.float32),
                         xy.astype(np.float32), p.jitter_key)

    def object_position(self, times_s: np.ndarray) -> np.ndarray:
        """(T,2) object centre: carried objects follow the dominant hand while held."""
        s = self.state(self.dominant, times_s)
        xy = np.repeat(self.object_xy[None, :], len(s), axis=0)
        if self.task.carry:
            xy += (s.hand_xy - self.plans[self.dominant].target_xy) * (s.phase == PHASE_CONTACT)[:, None]
        return xy

    # ---- glove ----------------------------------------------------------------
    def contact_grids(self, layout, hand: str, times_s: np.ndarray | None = None,
                      fill: float = 0.0) -> np.ndarray:
        """(T,H,W) float32 contact in [0,1] for `hand` wearing `layout`."""
        return contact_grids(layout, self.state(hand, times_s), fill=fill)

    # ---- camera ---------------------------------------------------------------
    def render(self, time_s: float, size: tuple[int, int], camera: str = "ego") -> np.ndarray:
        """One RGB frame (H,W,3) uint8 at `time_s`; size = (width, height)."""
        return next(self.render_frames(np.array([time_s]), size, camera))

    def render_frames(self, times_s: np.ndarray | None, size: tuple[int, int],
                      camera: str = "ego") -> Iterator[np.ndarray]:
        """Stream RGB frames (H,W,3) uint8 for `times_s` (default: video frame times)."""
        times = self.spec.frame_times() if times_s is None else np.asarray(times_s, np.float64)
        states = {h: self.state(h, times) for h in self.spec.hands}
        objects = self.object_position(times)
        view = _camera(camera, size, states)
        bg = _background(self.spec.scene, size[0], size[1])
        # Objects held at the fingertips stay visible in front of the hand; pressed,
        # pushed or fist-gripped objects are hidden under it.
        in_front = self.task.anchor in ("pinch", "tripod", "lateral", "hook")
        for i in range(len(times)):
            img = bg.copy()
            if not in_front:
                _draw_object(img, self.task.shape, objects[i], self.object_scale, self.object_rgb, view)
            for hand in self.spec.hands:
                s = states[hand]
                _draw_hand(img, hand, s.hand_xy[i], s.closure[i], view)
            if in_front:
                _draw_object(img, self.task.shape, objects[i], self.object_scale, self.object_rgb, view)
            yield img


# ---- glove painting -----------------------------------------------------------

def _block(block) -> tuple[str, str, tuple[int, int], tuple[int, int]]:
    """(name, place, rows, cols) of a layout block given as a dict or an object."""
    get = block.get if isinstance(block, dict) else (lambda k: getattr(block, k))
    return str(get("name")), str(get("place")), tuple(get("rows")), tuple(get("cols"))


def place_intensity(profile: dict[str, float], place: str) -> float:
    """Intensity of a block placed on `place` (a place or a whole group)."""
    if place in GROUPS:
        return max((v for k, v in profile.items() if k.split(".")[0] == place), default=0.0)
    if place not in PLACE_NAMES:
        raise ValueError(f"layout block place {place!r} is not a canonical place or group")
    return profile.get(place, 0.0)


def _block_jitter(jitter_key: int, name: str, t: np.ndarray) -> np.ndarray:
    """(T,2) blob-centre offset in units of the block extent: fixed part + slow drift."""
    rng = np.random.default_rng([jitter_key, stable_hash(name)])
    base = rng.uniform(-0.2, 0.2, 2)
    f, ph = rng.uniform(0.3, 1.0, 2), rng.uniform(0, 2 * np.pi, 2)
    return base[None, :] + 0.08 * np.sin(2 * np.pi * f[None, :] * t[:, None] + ph[None, :])


def _bend_fingers(layout, bend: np.ndarray) -> np.ndarray:
    """Finger index (0..4) of each bend cell: the finger block sharing its column, else -1."""
    out = np.full(len(bend), -1, dtype=np.int64)
    for blk in layout.blocks:
        _, place, _, cols = _block(blk)
        finger = place.split(".")[0]
        if finger in FINGERS:
            inside = (bend[:, 1] >= cols[0]) & (bend[:, 1] <= cols[1])
            out[inside & (out < 0)] = FINGERS.index(finger)
    return out


def contact_grids(layout, state: HandState, fill: float = 0.0) -> np.ndarray:
    """Paint (T,H,W) float32 in [0,1] for a glove `layout` from a hand state.

    Active blocks get a Gaussian blob (centre jittered per episode and block)
    scaled by place intensity x grip force; bend cells get the closure of
    their finger; cells that are neither live nor bend get `fill`
    (NaN for TouchAnything-style "no sensor").
    """
    rows, cols = (int(v) for v in layout.grid)
    T = len(state)
    grid = np.zeros((T, rows, cols), dtype=np.float32)
    profile = state.profile
    for blk in layout.blocks:
        name, place, (r0, r1), (c0, c1) = _block(blk)
        level = place_intensity(profile, place)
        if level <= 0:
            continue
        rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        h, w = r1 - r0 + 1, c1 - c0 + 1
        jit = _block_jitter(state.jitter_key, name, state.t)          # (T,2)
        cy = (r0 + r1) / 2 + jit[:, 0] * h                             # (T,)
        cx = (c0 + c1) / 2 + jit[:, 1] * w
        sy, sx = max(0.55 * h, 0.8), max(0.55 * w, 0.8)
        d2 = ((rr[None] - cy[:, None, None]) / sy) ** 2 + ((cc[None] - cx[:, None, None]) / sx) ** 2
        blob = level * state.force[:, None, None] * np.exp(-0.5 * d2)
        region = grid[:, r0:r1 + 1, c0:c1 + 1]
        np.maximum(region, blob.astype(np.float32), out=region)
    np.clip(grid, 0.0, 1.0, out=grid)
    live = np.asarray(layout.live_mask, dtype=bool)
    bend = np.asarray(layout.bend_cells, dtype=np.int64).reshape(-1, 2)
    keep = live.copy()
    if len(bend):
        finger = _bend_fingers(layout, bend)
        closure = np.concatenate([state.closure, state.closure.mean(axis=1, keepdims=True)], axis=1)
        # Per-cell spread so bend cells of one finger are not identical.
        spread = 0.85 + 0.15 * ((bend[:, 0] * 7 + bend[:, 1] * 3) % 5) / 4.0
        grid[:, bend[:, 0], bend[:, 1]] = np.clip(closure[:, finger] * spread[None, :], 0, 1)
        keep[bend[:, 0], bend[:, 1]] = True
    grid[:, ~keep] = fill
    return grid


def contact_grid(layout, state: HandState, fill: float = 0.0) -> np.ndarray:
    """(H,W) float32 grid for a single-frame state (`HandState.frame(i)`)."""
    if len(state) != 1:
        raise ValueError(f"contact_grid wants a single-frame state, got {len(state)} frames; "
                         "use contact_grids for episodes")
    return contact_grids(layout, state, fill=fill)[0]


# ---- hand geometry (world units: 1 = image short side) ------------------------

_PALM_W, _PALM_H = 0.15, 0.15
# Finger base x (fraction of palm half-width, radial side positive), segment lengths.
_FINGER_BASE = {"index": 0.72, "middle": 0.24, "ring": -0.24, "little": -0.72}
_FINGER_LEN = {"index": (0.055, 0.035, 0.028), "middle": (0.06, 0.04, 0.03),
               "ring": (0.055, 0.036, 0.028), "little": (0.045, 0.028, 0.024)}
_FINGER_SPLAY = {"index": 0.12, "middle": 0.0, "ring": -0.12, "little": -0.25}
_THUMB_LEN = (0.05, 0.04)
_JOINT_MAX = np.radians([80.0, 95.0, 60.0])  # flexion of each joint at closure 1


def _finger_points(closure: np.ndarray, hand: str) -> dict[str, np.ndarray]:
    """Joint positions (k,2) per digit relative to the palm centre, seen from the
    egocentric camera (back of the hand): flexion foreshortens the fingers so
    curled fingertips fold back over the palm; the thumb swings toward the index."""
    radial = -1.0 if hand == "right" else 1.0   # dorsal view: right thumb on the image left
    pts: dict[str, np.ndarray] = {}
    for k, finger in enumerate(FINGERS[1:], start=1):
        base = np.array([radial * _FINGER_BASE[finger] * _PALM_W / 2, -_PALM_H / 2])
        angle = np.cumsum(_JOINT_MAX * closure[k])
        splay = radial * _FINGER_SPLAY[finger] * (1.0 - 0.7 * closure[k])   # fingers fan out when open
        steps = np.array(_FINGER_LEN[finger])[:, None] * np.stack(
            [np.full(3, splay), -np.cos(angle)], axis=1)
        pts[finger] = base + np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    c = closure[0]
    base = np.array([radial * _PALM_W / 2, _PALM_H * 0.15])
    a0 = np.radians(50 - 45 * c)            # from pointing outward-up to pointing up/in
    a1 = a0 - np.radians(55 * c)
    d0 = np.array([radial * np.sin(a0), -np.cos(a0)])
    d1 = np.array([radial * np.sin(a1), -np.cos(a1)])
    p1 = base + _THUMB_LEN[0] * d0
    pts["thumb"] = np.vstack([base, p1, p1 + _THUMB_LEN[1] * d1])
    return pts


def _anchor_point(anchor: str, closure: np.ndarray, hand: str) -> np.ndarray:
    """The point of the hand (relative to the palm centre) that meets the object."""
    p = _finger_points(closure, hand)
    if anchor == "pinch":
        return (p["thumb"][-1] + p["index"][-1]) / 2
    if anchor == "tripod":
        return (p["thumb"][-1] + p["index"][-1] + p["middle"][-1]) / 3
    if anchor == "index_tip":
        return p["index"][-1]
    if anchor == "lateral":
        return (p["thumb"][-1] + p["index"][1]) / 2
    if anchor == "hook":
        return (p["index"][1] + p["little"][1]) / 2
    if anchor == "fist":
        return np.array([0.0, -_PALM_H * 0.45])
    if anchor == "palm":
        return np.zeros(2)
    raise ValueError(f"unknown anchor {anchor!r}")


# ---- drawing --------------------------------------------------------------------

@dataclass(frozen=True)
class _View:
    scale: float          # pixels per world unit
    origin: tuple         # pixel position of world (0,0)

    def px(self, xy) -> tuple[int, int]:
        return (int(round(self.origin[0] + xy[0] * self.scale)),
                int(round(self.origin[1] + xy[1] * self.scale)))

    def len(self, v: float) -> int:
        return max(1, int(round(v * self.scale)))


def _camera(camera: str, size: tuple[int, int], states: dict[str, HandState]) -> _View:
    """ego: the world square centred in the image; wrist_<hand>: 2x zoom on that hand's
    mean position (a head-fixed approximation of a wrist camera, cheap and deterministic)."""
    w, h = size
    s = float(min(w, h))
    if camera == "ego":
        return _View(s, (w / 2 - 0.5 * s, h / 2 - 0.5 * s))
    if camera.startswith("wrist_") and camera[6:] in states:
        c = states[camera[6:]].hand_xy.mean(axis=0) - np.array([0.0, 0.1])
        return _View(2 * s, (w / 2 - c[0] * 2 * s, h / 2 - c[1] * 2 * s))
    raise ValueError(f"unknown camera {camera!r}; use 'ego' or wrist_<hand> with hand in {list(states)}")


@lru_cache(maxsize=16)
def _background_cached(style: str, seed: int, w: int, h: int) -> np.ndarray:
    spec = SCENE_STYLES[style]
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), dtype=np.uint8)
    horizon = int(h * 0.38)
    img[:horizon] = spec["wall"]
    img[horizon:] = spec["table"]
    yy, xx = np.mgrid[0:h, 0:w]
    tex = spec["texture"]
    if tex == "wood":
        pattern = 10 * np.sin(yy / 9.0 + 2 * np.sin(xx / 60.0))
    elif tex == "grid":
        pattern = -18.0 * ((xx % 48 < 2) | (yy % 48 < 2))
    elif tex == "shelves":
        pattern = np.zeros((h, w))
        for y0 in range(8, horizon - 10, 36):      # coloured product rows on shelves
            colours = rng.integers(40, 230, size=(w // 24 + 1, 3))
            img[y0:y0 + 22] = np.repeat(colours, 24, axis=0)[:w][None]
    else:
        pattern = cv2.GaussianBlur(rng.normal(0, 14, (h, w)).astype(np.float32), (0, 0), 3)
    noise = rng.normal(0, 3, (h, w))
    out = np.clip(img.astype(np.float32) + (pattern + noise)[..., None], 0, 255).astype(np.uint8)
    cv2.line(out, (0, horizon), (w, horizon), (40, 40, 40), 2)
    out.setflags(write=False)
    return out


def _background(scene: str, w: int, h: int) -> np.ndarray:
    """Scene-dependent static backdrop (wall + table + texture), cached per size."""
    return _background_cached(scene_style(scene), stable_hash(scene), int(w), int(h))


_SKIN = (224, 172, 140)
_SKIN_DARK = (150, 100, 75)


def _draw_object(img, shape, xy, scale, rgb, view: _View) -> None:
    c = view.px(xy)
    r = view.len(0.04 * scale)
    dark = tuple(int(v * 0.55) for v in rgb)
    aa = cv2.LINE_AA
    if shape == "sphere":
        cv2.circle(img, c, r, rgb, -1, aa)
        cv2.circle(img, (c[0] - r // 3, c[1] - r // 3), max(1, r // 4), (255, 255, 255), -1, aa)
    elif shape == "bottle":
        cv2.rectangle(img, (c[0] - r, c[1] - 3 * r), (c[0] + r, c[1] + 3 * r), rgb, -1, aa)
        cv2.rectangle(img, (c[0] - r // 2, c[1] - 4 * r), (c[0] + r // 2, c[1] - 3 * r), dark, -1)
    elif shape == "button":
        cv2.rectangle(img, (c[0] - 2 * r, c[1] - r), (c[0] + 2 * r, c[1] + 2 * r), (90, 90, 95), -1)
        cv2.circle(img, c, max(2, int(r * 0.7)), rgb, -1, aa)
    elif shape == "cap":
        cv2.ellipse(img, c, (r, int(r * 0.8)), 0, 0, 360, rgb, -1, aa)
        cv2.ellipse(img, c, (r, int(r * 0.8)), 0, 0, 360, dark, 2, aa)
    elif shape == "key":
        cv2.circle(img, (c[0] - r, c[1]), int(r * 0.7), rgb, -1, aa)
        cv2.rectangle(img, (c[0] - r, c[1] - r // 5), (c[0] + 2 * r, c[1] + r // 5), rgb, -1)
    elif shape == "box":
        cv2.rectangle(img, (c[0] - 3 * r, c[1] - 2 * r), (c[0] + 3 * r, c[1] + 2 * r), rgb, -1)
        cv2.rectangle(img, (c[0] - 3 * r, c[1] - 2 * r), (c[0] + 3 * r, c[1] + 2 * r), dark, 2)
    elif shape == "bag":
        cv2.ellipse(img, (c[0], c[1] + r // 2), (int(1.4 * r), r), 0, 180, 360, dark, max(2, r // 4), aa)
        cv2.rectangle(img, (c[0] - 2 * r, c[1] + r // 2), (c[0] + 2 * r, c[1] + 4 * r), rgb, -1)
    else:
        raise ValueError(f"unknown object shape {shape!r}")


def _draw_hand(img, hand: str, xy, closure, view: _View) -> None:
    """Palm rectangle + five jointed finger polylines, closure-driven."""
    c = np.asarray(xy, dtype=np.float64)
    hw, hh = _PALM_W / 2, _PALM_H / 2
    palm = np.array([[-hw, -hh], [hw, -hh], [hw * 1.05, hh], [-hw * 1.05, hh]]) + c
    poly = np.array([view.px(p) for p in palm], dtype=np.int32)
    # forearm first so the palm covers its end
    cv2.line(img, view.px(c + [0, hh]), view.px(c + [0, hh + 0.25]), _SKIN_DARK, view.len(0.11), cv2.LINE_AA)
    cv2.fillConvexPoly(img, poly, _SKIN, cv2.LINE_AA)
    cv2.polylines(img, [poly], True, _SKIN_DARK, 2, cv2.LINE_AA)
    for name, pts in _finger_points(np.asarray(closure, np.float64), hand).items():
        width = view.len(0.026 if name != "little" else 0.021)
        p = np.array([view.px(q) for q in pts + c], dtype=np.int32)
        cv2.polylines(img, [p], False, _SKIN_DARK, width + 3, cv2.LINE_AA)
        cv2.polylines(img, [p], False, _SKIN, width, cv2.LINE_AA)
