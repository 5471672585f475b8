"""Hand geometry of the synthetic world (world units: 1 = image short side).

Where the joints of each digit sit for a given finger closure, seen from the
egocentric camera, and which point of the hand meets the object for each
task anchor. The world places the hand with `anchor_point`; the renderer
draws `finger_points`.
"""

from __future__ import annotations

import numpy as np

from htdata.synthetic.tasks import FINGERS

PALM_W, PALM_H = 0.15, 0.15
# Finger base x (fraction of palm half-width, radial side positive), segment lengths.
_FINGER_BASE = {"index": 0.72, "middle": 0.24, "ring": -0.24, "little": -0.72}
_FINGER_LEN = {"index": (0.055, 0.035, 0.028), "middle": (0.06, 0.04, 0.03),
               "ring": (0.055, 0.036, 0.028), "little": (0.045, 0.028, 0.024)}
_FINGER_SPLAY = {"index": 0.12, "middle": 0.0, "ring": -0.12, "little": -0.25}
_THUMB_LEN = (0.05, 0.04)
_JOINT_MAX = np.radians([80.0, 95.0, 60.0])  # flexion of each joint at closure 1


def finger_points(closure: np.ndarray, hand: str) -> dict[str, np.ndarray]:
    """Joint positions (k,2) per digit relative to the palm centre, seen from the
    egocentric camera (back of the hand): flexion foreshortens the fingers so
    curled fingertips fold back over the palm; the thumb swings toward the index."""
    radial = -1.0 if hand == "right" else 1.0   # dorsal view: right thumb on the image left
    pts: dict[str, np.ndarray] = {}
    for k, finger in enumerate(FINGERS[1:], start=1):
        base = np.array([radial * _FINGER_BASE[finger] * PALM_W / 2, -PALM_H / 2])
        angle = np.cumsum(_JOINT_MAX * closure[k])
        splay = radial * _FINGER_SPLAY[finger] * (1.0 - 0.7 * closure[k])   # fingers fan out when open
        steps = np.array(_FINGER_LEN[finger])[:, None] * np.stack(
            [np.full(3, splay), -np.cos(angle)], axis=1)
        pts[finger] = base + np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    c = closure[0]
    base = np.array([radial * PALM_W / 2, PALM_H * 0.15])
    a0 = np.radians(50 - 45 * c)            # from pointing outward-up to pointing up/in
    a1 = a0 - np.radians(55 * c)
    d0 = np.array([radial * np.sin(a0), -np.cos(a0)])
    d1 = np.array([radial * np.sin(a1), -np.cos(a1)])
    p1 = base + _THUMB_LEN[0] * d0
    pts["thumb"] = np.vstack([base, p1, p1 + _THUMB_LEN[1] * d1])
    return pts


def anchor_point(anchor: str, closure: np.ndarray, hand: str) -> np.ndarray:
    """The point of the hand (relative to the palm centre) that meets the object."""
    p = finger_points(closure, hand)
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
        return np.array([0.0, -PALM_H * 0.45])
    if anchor == "palm":
        return np.zeros(2)
    raise ValueError(f"unknown anchor {anchor!r}")
