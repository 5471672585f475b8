"""A deterministic synthetic "world" for the sample corpus.

One hidden state per episode (task, object, hand trajectory, grip force,
finger closure) drives BOTH what a glove would feel (`World.contact_grids`,
painted by glove.py) and what the egocentric camera sees
(`World.render_frames`, drawn by render.py), so that an RGB frame predicts
the contact map: fingers close when force rises, the object sits between
thumb and index for a pinch, under the palm for a palm push. tasks.py holds
the task profiles and scene styles, hand.py the hand geometry.

Everything is a pure function of (task, scene, seed) and continuous time in
seconds, so a 100 Hz tactile stream and a 30 Hz video of the same episode
come from the same world. Stable hashes (crc32), never Python's salted hash().
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from htdata.format.table import HANDS
from htdata.synthetic.glove import contact_grids
from htdata.synthetic.hand import anchor_point
from htdata.synthetic.render import background, camera_view, draw_hand, draw_object, draw_support_pad
from htdata.synthetic.state import HandState
from htdata.synthetic.tasks import TASKS, scene_style, stable_hash

PHASE_APPROACH, PHASE_CONTACT, PHASE_RELEASE = 0, 1, 2
# When contact happens in an episode (EpisodeSpec.timing). "classic" is the world's first timing and
# the default: one contact starting 15-30 % in and ending by 90 %, so the relative position in the
# episode alone told contact apart (AUROC 0.96, issue #45). The others were appended for that: an idle
# lead-in and tail of varying length, two contacts, a clip that starts mid-grasp or ends holding.
# A classic episode keeps its bytes; `contact_windows` draws the others from their own stream.
TIMINGS = ("classic", "late", "mid_grasp", "two_contacts", "held_to_end", "early")
# A support hand that feels contact (the task's support profile) closes on the pad it presses;
# one that feels nothing hangs half open in the air. The RGB-to-tactile held-out check failed
# while both looked alike (docs/HANDTOUCH.md, "Held-out RGB-to-tactile").
SUPPORT_CLOSURE_TOUCH, SUPPORT_CLOSURE_IDLE = 0.65, 0.3


@dataclass
class EpisodeSpec:
    """One synthetic episode: what happens (task, scene), its seed and timing."""

    task: str
    scene: str
    seed: int
    n_frames: int
    fps: float = 30.0
    hands: tuple[str, ...] = ("right",)
    timing: str = "classic"       # TIMINGS: when contact happens


    def validate(self) -> "EpisodeSpec":
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; known: {', '.join(TASKS)}")
        scene_style(self.scene)
        if int(self.n_frames) < 1:
            raise ValueError(f"episode {self.task}/{self.scene}/{self.seed}: n_frames must be >= 1")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise ValueError(f"episode {self.task}/{self.scene}/{self.seed}: fps must be > 0")
        if self.timing not in TIMINGS:
            raise ValueError(f"episode {self.task}/{self.scene}/{self.seed}: timing {self.timing!r} is not "
                             f"one of {TIMINGS}")
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
    # (start, end) fractions of each contact for a timing other than "classic" (which uses a, b);
    # a start < 0 is a clip that begins mid-grasp, an end > 1 one that ends holding
    windows: tuple[tuple[float, float], ...] = ()
    approach: float = 0.0     # fraction of the episode a reach in (and out) takes, varied timings


def contact_windows(timing: str, rng: np.random.Generator, ramp: float) -> tuple[tuple[float, float], ...]:
    """The contacts of one hand for a varied `timing` (TIMINGS), as (start, end) episode fractions."""
    full = ramp + 0.02                   # a start this far before 0 is already at full force at u = 0
    if timing == "late":                 # a long idle lead-in; some hold on past the end
        a = rng.uniform(0.42, 0.58)
        return ((a, a + rng.uniform(0.40, 0.60)),)
    if timing == "mid_grasp":            # the recording starts while the hand holds
        return ((-full, rng.uniform(0.40, 0.60)),)
    if timing == "two_contacts":         # one near each end, idle between
        a1 = rng.uniform(0.0, 0.06)
        a2 = rng.uniform(0.62, 0.72)
        return ((a1, a1 + rng.uniform(0.22, 0.32)), (a2, a2 + rng.uniform(0.25, 0.40)))
    if timing == "held_to_end":          # the recording stops while the hand still holds
        return ((rng.uniform(0.35, 0.60), 1.0 + full),)
    if timing == "early":                # a long idle tail
        a = rng.uniform(0.0, 0.08)
        return ((a, a + rng.uniform(0.40, 0.55)),)
    raise ValueError(f"contact_windows: no windows for timing {timing!r}")


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
        if spec.timing != "classic":     # drawn after, from their own stream: the draws above keep their values
            for h, p in self.plans.items():
                t_rng = np.random.default_rng([spec.seed & 0xFFFFFFFF, stable_hash(spec.task),
                                               stable_hash(spec.scene), stable_hash("timing", spec.timing, h)])
                p.windows = contact_windows(spec.timing, t_rng, p.ramp)
                p.approach = float(t_rng.uniform(0.10, 0.22))

    # ---- hidden state -------------------------------------------------------
    def _plan(self, rng: np.random.Generator, hand: str) -> _HandPlan:
        a = rng.uniform(0.15, 0.30)
        b = a + rng.uniform(0.40, 0.55)
        side = 1.0 if hand == "right" else -1.0
        if hand == self.dominant:
            closure = np.array(self.task.closure)
            offset = anchor_point(self.task.anchor, closure, hand)
            target = self.object_xy - offset
        else:  # support hand steadies things beside the object (on its pad when it feels contact)
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
        if p.windows:
            return self._windowed_state(hand, t, u, p)
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
        target_closure = np.array(self.task.closure if role == "dominant" else (self._support_closure(),) * 5)
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

    def _windowed_state(self, hand: str, t: np.ndarray, u: np.ndarray, p: _HandPlan) -> HandState:
        """`state` for a varied timing: the classic time course once per contact window, the hand
        reaching in over `p.approach` before each and out after (max over the windows)."""
        envelope, shape, reach, lift = (np.zeros_like(u) for _ in range(4))
        inside = np.zeros(u.shape, bool)
        pre = 0.08
        for a, b in p.windows:
            within = (u >= a) & (u < b)
            inside |= within
            envelope = np.maximum(envelope, np.where(within, _smoothstep((u - a) / p.ramp) *
                                                     _smoothstep((b - u) / p.ramp), 0.0))
            shape = np.maximum(shape, _smoothstep((u - a + pre) / (p.ramp + pre)) *
                               _smoothstep((b + pre - u) / (p.ramp + pre)))
            reach = np.maximum(reach, _smoothstep((u - a + p.approach) / p.approach) *
                               _smoothstep((b + p.approach - u) / p.approach))
            lift = np.maximum(lift, np.where(within, np.sin(np.pi * np.clip((u - a) / (b - a), 0, 1)), 0.0))
        first = min(a for a, _ in p.windows)
        phase = np.where(inside, PHASE_CONTACT, np.where(u < first, PHASE_APPROACH, PHASE_RELEASE))
        tremor = sum(np.sin(2 * np.pi * f * t + ph) for f, ph in zip(p.tremor_f, p.tremor_p)) / 3
        slow = 0.08 * np.sin(2 * np.pi * 0.7 * t + p.tremor_p[0])
        force = np.clip(p.peak * envelope * (1.0 + slow + 0.04 * tremor), 0.0, 1.0)
        role = "dominant" if hand == self.dominant else "support"
        target_closure = np.array(self.task.closure if role == "dominant" else (self._support_closure(),) * 5)
        closure = np.clip(shape[:, None] * target_closure[None, :], 0.0, 1.0)
        xy = p.start_xy[None, :] + reach[:, None] * (p.target_xy - p.start_xy)[None, :]
        if self.task.carry and role == "dominant":
            xy[:, 1] -= lift * 0.06
        xy += 0.003 * np.stack([np.sin(2 * np.pi * p.tremor_f[1] * t + p.tremor_p[2]),
                                np.cos(2 * np.pi * p.tremor_f[2] * t + p.tremor_p[1])], axis=1)
        return HandState(self.spec.task, hand, role, t, phase.astype(np.int8),
                         force.astype(np.float32), closure.astype(np.float32),
                         xy.astype(np.float32), p.jitter_key)

    def _support_closure(self) -> float:
        return SUPPORT_CLOSURE_TOUCH if self.task.support else SUPPORT_CLOSURE_IDLE

    def support_pads(self) -> list[np.ndarray]:
        """Where the support hands that feel contact press (their palm centre while touching)."""
        if not self.task.support:
            return []
        return [p.target_xy for h, p in self.plans.items() if h != self.dominant]

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
        view = camera_view(camera, size, states)
        bg = background(self.spec.scene, size[0], size[1])
        # Objects held at the fingertips stay visible in front of the hand; pressed,
        # pushed or fist-gripped objects are hidden under it.
        in_front = self.task.anchor in ("pinch", "tripod", "lateral", "hook")
        pads = self.support_pads()
        if pads:   # static scenery, under the hands (on a copy: the background is cached)
            bg = bg.copy()
            for pad in pads:
                draw_support_pad(bg, pad, view)
        for i in range(len(times)):
            img = bg.copy()
            if not in_front:
                draw_object(img, self.task.shape, objects[i], self.object_scale, self.object_rgb, view)
            for hand in self.spec.hands:
                s = states[hand]
                draw_hand(img, hand, s.hand_xy[i], s.closure[i], view)
            if in_front:
                draw_object(img, self.task.shape, objects[i], self.object_scale, self.object_rgb, view)
            yield img
