"""Plan and write the synthetic raw corpus in the three source formats.

`plan_corpus(cfg)` decides every episode (cheap, no I/O) so tests can check
coverage (tasks x scenes x formats) without writing; `write_corpus(cfg)`
renders each planned episode from its `World` and hands it to the format
writers in `htdata.synthetic.formats`, reproducing each source's quirks:

- OpenTouch: one HDF5 per scene, demo ids padded differently per file,
  inverted units 0..3072 with sensor noise, BGR-swapped JPEGs, annotations.csv.
- TouchAnything: both hands, right grid stored mirrored (its layout says so),
  NaN at no-sensor cells, bend values, chest video 1-2 frames longer than the
  npz for some episodes, epoch-second `ts`, split.json at the root.
- native: 100 Hz tactile on the glove's own clock vs 30 Hz video, clock offset.

`mispair_rgb`, `rgb_lag_frames` and `reverse_rgb` write a deliberately broken control corpus
(htdata.synthetic.controls: RGB of another episode, behind the glove, played backwards).
"""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from htdata.errors import ArgumentError
from htdata.fileio import write_json_atomic
from htdata.glove.glovevalue import is_inverted
from htdata.glove.layouts import load_layout
from htdata.source.adapters import ADAPTERS
from htdata.synthetic.controls import control_video, mark_controls
from htdata.synthetic.formats import (
    NativeHand,
    NativeRecording,
    OpenTouchClip,
    TouchAnythingEpisode,
    write_native_recording,
    write_opentouch_annotations,
    write_opentouch_scene,
    write_touchanything_episode,
    write_touchanything_split,
)
from htdata.synthetic.tasks import TASKS, scene_style, stable_hash
from htdata.synthetic.world import TIMINGS, EpisodeSpec, World

SCALES = ("tiny", "small", "medium")

OPENTOUCH_LAYOUT = "opentouch_right_16x16"
TA_LAYOUTS = {"left": "touchanything_left_21x21", "right": "touchanything_right_21x21"}
OPENTOUCH_IMAGE = (512, 512)     # Aria RGB, downsized
TA_IMAGE = (640, 480)
NATIVE_IMAGE = (480, 480)
OPENTOUCH_MAX = 3072.0           # firmware units: 3072 = no load, 0 = saturated
OPENTOUCH_NOISE = 6.0            # sensor noise, raw units (std)
TA_NOISE = 0.004                 # sensor noise on live cells, [0,1] units (std)
NATIVE_TACTILE_HZ = 100.0
VIDEO_FPS = 30.0
TA_UNSEEN_TASK = "hook_carry"    # TouchAnything's own split holds this task out

# Per scale: scenes, tasks and clips per (scene, task), frame-count range.
_PLANS = {
    "tiny": {
        "opentouch": {"scenes": ("home_kitchen_p1", "office_desk_p2"),
                      "tasks": ("pinch_pick", "power_grasp"), "per_cell": 1, "frames": (47, 52)},
        "touchanything": {"scenes": ("Home",), "tasks": ("pinch_pick", "power_grasp"),
                          "per_cell": 1, "frames": (40, 46)},
        "native": {"recordings": (("pinch_pick", "lab_bench", ("right",), "mp4"),
                                  ("power_grasp", "lab_bench", ("left", "right"), "mp4")),
                   "frames": (36, 42)},
    },
    "small": {
        "opentouch": {"scenes": ("home_kitchen_p1", "office_desk_p2", "grocery_target_p1"),
                      "tasks": tuple(TASKS), "per_cell": 1, "frames": (47, 90)},
        "touchanything": {"scenes": ("Home", "Office", "Retail"), "tasks": tuple(TASKS),
                          "per_cell": 1, "frames": (45, 75)},
        "native": {"recordings": (("pinch_pick", "lab_bench", ("right",), "mp4"),
                                  ("press_button", "lab_bench", ("right",), "jpeg"),
                                  ("palm_push", "workbench_lab", ("right",), "mp4"),
                                  ("power_grasp", "lab_bench", ("left", "right"), "mp4")),
                   "frames": (60, 90)},
    },
}
# The ingest benchmark's worker-scaling corpus: 3x small (3 clips per cell, each native recording 4 times),
# so 2 workers get ~60 units and the unit count does not cap the speed-up (21 units over 2 cap it at 1.91x).
_PLANS["medium"] = {
    "opentouch": {**_PLANS["small"]["opentouch"], "per_cell": 3},
    "touchanything": {**_PLANS["small"]["touchanything"], "per_cell": 3},
    "native": {**_PLANS["small"]["native"], "recordings": _PLANS["small"]["native"]["recordings"] * 4},
}
# One corpus folder per source adapter the corpus plans (names from the adapter registry).
FORMATS = tuple(name for name in ADAPTERS if name in _PLANS["small"])


@dataclass
class CorpusConfig:
    """What `htdata sample` writes."""

    out: Path
    seed: int = 0
    scale: str = "small"
    formats: tuple[str, ...] = FORMATS
    overwrite: bool = False
    progress: bool = True
    mispair_rgb: bool = False     # the control corpus (module docstring): RGB of another episode
    rgb_lag_frames: int = 0       # a control corpus: video K frames behind the glove
    reverse_rgb: bool = False     # a control corpus: each episode's video played backwards
    # (lo, hi) video frames per episode instead of the scale's range (None: the scale's; byte-identical)
    episode_frames: tuple[int, int] | None = None

    def validate(self) -> "CorpusConfig":
        self.out = Path(self.out)
        if self.scale not in SCALES:
            raise ArgumentError(f"scale must be one of {SCALES}, got {self.scale!r}")
        unknown = [f for f in self.formats if f not in FORMATS]
        if unknown or not self.formats:
            raise ArgumentError(f"formats must be a non-empty subset of {FORMATS}, got {self.formats}")
        self.formats = tuple(f for f in FORMATS if f in self.formats)
        if not 0 <= int(self.rgb_lag_frames) <= 300:
            raise ArgumentError(f"rgb_lag_frames must be in [0, 300] video frames, got {self.rgb_lag_frames}")
        if sum([bool(self.mispair_rgb), int(self.rgb_lag_frames) > 0, bool(self.reverse_rgb)]) > 1:
            raise ArgumentError("one broken control at a time: --mispair-rgb, --rgb-lag-frames or --reverse-rgb")
        if not 0 <= int(self.seed) < 2**32:
            raise ArgumentError(f"seed must be in [0, 2**32), got {self.seed}")
        if self.episode_frames is not None:
            lo, hi = (int(v) for v in self.episode_frames)
            if not 2 <= lo <= hi <= 100_000:
                raise ArgumentError(f"episode_frames must be 2 <= lo <= hi <= 100000, got {self.episode_frames}")
            self.episode_frames = (lo, hi)
        return self


@dataclass(frozen=True)
class PlannedEpisode:
    """One episode of the corpus: its source format, world and on-disk name."""

    fmt: str
    spec: EpisodeSpec
    name: str                     # demo id / "Scene/task/traj" / recording folder
    extra: dict = field(default_factory=dict, hash=False, compare=False)


def _episode_seed(seed: int, *parts) -> int:
    return stable_hash(seed, *parts) & 0x7FFFFFFF


def _timing(seed: int, task: str, k: int) -> str:
    """The contact timing of a task's k-th episode in the corpus: every timing of TIMINGS in turn (so each
    task, the held-out ones too, holds all of them), the turn shifted by task and seed."""
    return TIMINGS[(k + stable_hash("timing", task) + int(seed)) % len(TIMINGS)]


def _n_frames(seed: int, frames: tuple[int, int]) -> int:
    return int(np.random.default_rng(seed).integers(frames[0], frames[1] + 1))


def _plan_opentouch(seed: int, spec: dict) -> list[PlannedEpisode]:
    out = []
    for s_idx, scene in enumerate(spec["scenes"]):
        rng = np.random.default_rng(_episode_seed(seed, "opentouch-ids", scene))
        pad = 2 if s_idx % 2 == 0 else 3          # demo_07 in one file, demo_007 in the next
        number = int(rng.integers(0, 10))
        for task in spec["tasks"]:
            for k in range(spec["per_cell"]):
                number += int(rng.integers(1, 4))   # ids have gaps, like the release
                ep_seed = _episode_seed(seed, "opentouch", scene, task, k)
                ep = EpisodeSpec(task, scene, ep_seed, _n_frames(ep_seed, spec["frames"]), VIDEO_FPS, ("right",),
                                 _timing(seed, task, s_idx * spec["per_cell"] + k))
                out.append(PlannedEpisode("opentouch", ep.validate(), f"demo_{number:0{pad}d}"))
    return out


def _traj_id(seed: int) -> str:
    """TouchAnything trajectory folder name: YYYYMMDD_HHMMSS_mmm."""
    rng = np.random.default_rng(seed)
    day, h, m, s, ms = (int(rng.integers(1, 29)), int(rng.integers(8, 19)), int(rng.integers(0, 60)),
                        int(rng.integers(0, 60)), int(rng.integers(0, 1000)))
    return f"202603{day:02d}_{h:02d}{m:02d}{s:02d}_{ms:03d}"


def _plan_touchanything(seed: int, spec: dict) -> list[PlannedEpisode]:
    out = []
    for task in spec["tasks"]:
        k_task = 0
        for scene in spec["scenes"]:
            for k in range(spec["per_cell"]):
                ep_seed = _episode_seed(seed, "touchanything", scene, task, k)
                n = _n_frames(ep_seed, spec["frames"])
                # after the OpenTouch clips of the task: a task's six small-corpus episodes get six timings
                timing = _timing(seed, task, len(spec["scenes"]) * spec["per_cell"] + k_task)
                ep = EpisodeSpec(task, scene, ep_seed, n, VIDEO_FPS, ("left", "right"), timing).validate()
                if task == TA_UNSEEN_TASK:
                    split = "test_unseen"
                else:
                    split = {1: "val", 2: "test_seen"}.get(k_task % 4, "train")
                # Every other episode's video runs 1-2 frames past the npz (release quirk).
                video_extra = 1 + ep_seed % 2 if k_task % 2 == 0 else 0
                out.append(PlannedEpisode("touchanything", ep, f"{scene}/{task}/{_traj_id(ep_seed)}",
                                          {"split": split, "video_extra": video_extra}))
                k_task += 1
    return out


def _plan_native(seed: int, spec: dict) -> list[PlannedEpisode]:
    out = []
    for k, (task, scene, hands, storage) in enumerate(spec["recordings"]):
        ep_seed = _episode_seed(seed, "native", scene, task, k)
        ep = EpisodeSpec(task, scene, ep_seed, _n_frames(ep_seed, spec["frames"]), VIDEO_FPS, hands,
                         _timing(seed, "native", k))
        layouts = ({"right": OPENTOUCH_LAYOUT} if hands == ("right",) else dict(TA_LAYOUTS))
        out.append(PlannedEpisode("native", ep.validate(), f"rec_{k:03d}_{task}",
                                  {"layouts": layouts, "video_storage": storage}))
    return out


def plan_corpus(cfg: CorpusConfig) -> list[PlannedEpisode]:
    """Every episode the corpus will hold, in writing order (no I/O)."""
    cfg.validate()
    plan = _PLANS[cfg.scale]
    planners = {"opentouch": _plan_opentouch, "touchanything": _plan_touchanything, "native": _plan_native}
    out = []
    for fmt in cfg.formats:
        spec = plan[fmt] if cfg.episode_frames is None else {**plan[fmt], "frames": cfg.episode_frames}
        out += mark_controls(planners[fmt](int(cfg.seed), spec), cfg.mispair_rgb, cfg.rgb_lag_frames,
                             cfg.reverse_rgb)
    return out


# ---- raw units ----------------------------------------------------------------

def opentouch_raw(contact: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """[0,1] contact -> inverted firmware units: 3072*(1-c) + noise, clipped to 0..3072."""
    raw = OPENTOUCH_MAX * (1.0 - contact) + rng.normal(0.0, OPENTOUCH_NOISE, contact.shape)
    return np.clip(raw, 0.0, OPENTOUCH_MAX).astype(np.float32)


def touchanything_raw(contact: np.ndarray, layout, rng: np.random.Generator) -> np.ndarray:
    """[0,1] contact (NaN at no-sensor cells) + small noise on pressure cells, kept in [0,1]."""
    out = contact.copy()
    live = np.asarray(layout.live_mask, bool)
    out[:, live] = np.clip(out[:, live] + np.abs(rng.normal(0.0, TA_NOISE, (len(out), int(live.sum())))), 0, 1)
    return out.astype(np.float32)


def native_raw(contact: np.ndarray, layout, rng: np.random.Generator) -> np.ndarray:
    """Raw units of the layout's own value convention."""
    if is_inverted(layout.value.get("convention")):
        top = float(layout.value["max"])
        raw = top * (1.0 - contact) + rng.normal(0.0, top * OPENTOUCH_NOISE / OPENTOUCH_MAX, contact.shape)
        return np.clip(raw, 0.0, top).astype(np.float32)
    return (touchanything_raw(contact, layout, rng) * float(layout.value.get("max", 1.0))).astype(np.float32)


def _fill_for(layout) -> float:
    """No-sensor cells: NaN for direct-valued (TouchAnything-style) gloves, no load otherwise."""
    return float("nan") if not is_inverted(layout.value.get("convention")) else 0.0


# ---- writers ------------------------------------------------------------------

def _write_opentouch(out: Path, episodes: list[PlannedEpisode], seed: int, bar) -> dict:
    layout = load_layout(OPENTOUCH_LAYOUT)
    by_scene: dict[str, list[PlannedEpisode]] = {}
    for ep in episodes:
        by_scene.setdefault(ep.spec.scene, []).append(ep)
    rows, frames = [], 0
    for scene, eps in by_scene.items():
        clips = []
        for ep in eps:
            world = World(ep.spec)
            rng = np.random.default_rng(_episode_seed(seed, "opentouch-noise", scene, ep.name))
            contact = world.contact_grids(layout, "right", fill=_fill_for(layout))
            t0 = int(rng.integers(10**12, 2 * 10**12))           # device clock, ns
            ts = t0 + np.round(ep.spec.frame_times() * 1e9).astype(np.int64) + rng.integers(-200_000, 200_000, ep.spec.n_frames)
            clips.append(OpenTouchClip(ep.name, np.sort(ts), opentouch_raw(contact, rng),
                                       control_video(ep, world, None, OPENTOUCH_IMAGE, seed)))
            task = TASKS[ep.spec.task]
            rows.append({"id": f"{scene}::{ep.name}", "action": ep.spec.task, "grip_type": task.anchor,
                         "object_name": task.shape, "object_category": "synthetic",
                         "environment": scene_style(scene)})
            frames += ep.spec.n_frames
        # The writer pulls frames from each clip's generator as it encodes.
        write_opentouch_scene(out / "opentouch" / f"{scene}.hdf5", clips, swap_rb=True)
        bar.update(len(eps))
    write_opentouch_annotations(out / "opentouch" / "annotations.csv", rows)
    return {"episodes": len(episodes), "frames": frames, "files": len(by_scene) + 1}


def _write_touchanything(out: Path, episodes: list[PlannedEpisode], seed: int, bar) -> dict:
    layouts = {h: load_layout(i) for h, i in TA_LAYOUTS.items()}
    split: dict[str, list[str]] = {}
    frames = 0
    for ep in episodes:
        world = World(ep.spec)
        rng = np.random.default_rng(_episode_seed(seed, "touchanything-noise", ep.name))
        # The right layout describes the grid AS STORED (mirrored columns), so
        # painting through it yields the release's mirrored right grid.
        grids = {h: touchanything_raw(world.contact_grids(lay, h, fill=float("nan")), lay, rng)
                 for h, lay in layouts.items()}
        n_video = ep.spec.n_frames + int(ep.extra["video_extra"])
        video_times = np.arange(n_video) / ep.spec.fps
        t0 = 1.7740e9 + float(rng.uniform(0, 1e6))            # epoch seconds (2026)
        ts = t0 + ep.spec.frame_times() + rng.normal(0, 0.002, ep.spec.n_frames)
        write_touchanything_episode(
            out / "touchanything" / ep.name,
            TouchAnythingEpisode(grids["left"], grids["right"], control_video(ep, world, video_times, TA_IMAGE, seed),
                                 np.maximum.accumulate(ts)))
        split.setdefault(ep.extra["split"], []).append(f"TouchAnything/{ep.name}")
        frames += ep.spec.n_frames
        bar.update(1)
    write_touchanything_split(out / "touchanything", split)
    return {"episodes": len(episodes), "frames": frames, "files": len(episodes) + 1}


def _write_native(out: Path, episodes: list[PlannedEpisode], seed: int, bar) -> dict:
    frames = 0
    for ep in episodes:
        world = World(ep.spec)
        rng = np.random.default_rng(_episode_seed(seed, "native-noise", ep.name))
        video_start = int(rng.integers(10**9, 10**10))
        hands = {}
        tactile_times = ep.spec.frame_times(NATIVE_TACTILE_HZ)
        for hand, layout_id in ep.extra["layouts"].items():
            layout = load_layout(layout_id)
            contact = world.contact_grids(layout, hand, tactile_times, fill=_fill_for(layout))
            glove_start = int(rng.integers(10**11, 10**12))      # the glove's own clock
            ts = glove_start + np.round(tactile_times * 1e9).astype(np.int64)
            hands[hand] = NativeHand(layout_id, native_raw(contact, layout, rng), ts,
                                     clock_offset_ns=video_start - glove_start)
        video_times = ep.spec.frame_times()
        write_native_recording(out / "native" / ep.name, NativeRecording(
            task=ep.spec.task, scene=ep.spec.scene,
            video_frames=control_video(ep, world, video_times, NATIVE_IMAGE, seed),
            video_timestamps_ns=video_start + np.round(video_times * 1e9).astype(np.int64),
            hands=hands, operator="synthetic", notes="htdata sample corpus",
            video_storage=ep.extra["video_storage"], extra={"seed": ep.spec.seed}))
        frames += ep.spec.n_frames
        bar.update(1)
    return {"episodes": len(episodes), "frames": frames, "files": len(episodes)}


_WRITERS = {"opentouch": _write_opentouch, "touchanything": _write_touchanything, "native": _write_native}


# Written last by write_corpus: OUT holds a finished corpus of this seed, scale and formats.
# A crash mid-write leaves no marker, so `htdata sample --reuse` (the Makefile, the smoke,
# the bench) writes the corpus again instead of ingesting half of it.
COMPLETE_MARKER = ".complete"


# The world's version: 2 since contact timing varies between episodes (world.TIMINGS); a corpus written
# by an older world is not reused.
WORLD_VERSION = 2


def corpus_identity(cfg: CorpusConfig) -> dict:
    ident = {"seed": int(cfg.seed), "scale": cfg.scale, "formats": list(cfg.formats), "world": WORLD_VERSION}
    if cfg.mispair_rgb:
        ident["mispair_rgb"] = True
    if cfg.rgb_lag_frames:
        ident["rgb_lag_frames"] = int(cfg.rgb_lag_frames)
    if cfg.reverse_rgb:
        ident["reverse_rgb"] = True
    if cfg.episode_frames is not None:
        ident["episode_frames"] = list(cfg.episode_frames)
    return ident


def corpus_complete(cfg: CorpusConfig) -> bool:
    """True when cfg.out holds a finished corpus written with cfg's seed, scale and formats."""
    try:
        doc = json.loads((Path(cfg.out) / COMPLETE_MARKER).read_text())
    except (OSError, ValueError):
        return False
    return doc == corpus_identity(cfg.validate())


def write_corpus(cfg: CorpusConfig) -> dict:
    """Write the planned corpus under cfg.out, then its COMPLETE_MARKER; return per-format counts."""
    from tqdm import tqdm

    episodes = plan_corpus(cfg)
    (cfg.out / COMPLETE_MARKER).unlink(missing_ok=True)      # from here until the end: incomplete
    for fmt in cfg.formats:
        target = cfg.out / fmt
        if target.exists() and any(target.iterdir()):
            if not cfg.overwrite:
                raise FileExistsError(f"{target} exists and is not empty; pass --overwrite to replace it")
            shutil.rmtree(target)
    summary = {}
    with tqdm(total=len(episodes), desc="htdata sample", unit="ep", file=sys.stderr,
              disable=not cfg.progress) as bar:
        for fmt in cfg.formats:
            bar.set_postfix_str(fmt)
            summary[fmt] = _WRITERS[fmt](cfg.out, [e for e in episodes if e.fmt == fmt], int(cfg.seed), bar)
    write_json_atomic(cfg.out / COMPLETE_MARKER, corpus_identity(cfg))
    return summary
