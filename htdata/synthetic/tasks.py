"""What happens in a synthetic episode: task profiles, place vocabulary, scene styles.

A task says how the hand touches (contact intensity per canonical place for
the dominant and the support hand, finger closure, which hand point meets
the object) and what the object looks like; a scene name picks a backdrop
style by keyword. `stable_hash` seeds everything: crc32, never Python's
salted hash(), so a corpus is identical across processes.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any

FINGERS = ("thumb", "index", "middle", "ring", "little")
GROUPS = FINGERS + ("palm",)
# Canonical place names (docs/LAYOUTS.md, "The canonical hand").
PLACE_NAMES: tuple[str, ...] = (
    "thumb.distal", "thumb.proximal",
    *(f"{f}.{p}" for f in FINGERS[1:] for p in ("distal", "middle", "proximal")),
    "palm.upper_ulnar", "palm.upper_radial", "palm.lower_ulnar", "palm.lower_radial",
)


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
    anchor: str                     # which hand point meets the object (see hand.anchor_point)
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
    # power_grasp's touch, support and hand shape on a new object: the smoke's held-out task (a new
    # task, not new physics, as the paper's OOD). Appended, so every other episode keeps its bytes.
    _task("cup_grasp", {"palm": 0.8, "thumb": 0.9, "index": 1.0, "middle": 1.0,
                        "ring": 0.9, "little": 0.75},
          {"palm": 0.4}, (0.85, 0.9, 0.9, 0.9, 0.9), "fist", "cup", (245, 130, 185), True),
)}
# Tasks that share one touch and hand shape on different objects: (held out, its training twin).
TWINS: dict[str, str] = {"cup_grasp": "power_grasp"}

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

