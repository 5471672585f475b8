"""What the egocentric camera sees in the synthetic world: backdrop, object, hands.

Pure drawing with OpenCV on uint8 RGB frames; the world decides where things
are (`World.render_frames`) and calls these. `camera_view` maps world units
to pixels for the ego view or a zoomed wrist view.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from htdata.synthetic.hand import PALM_H, PALM_W, finger_points
from htdata.synthetic.state import HandState
from htdata.synthetic.tasks import SCENE_STYLES, scene_style, stable_hash


@dataclass(frozen=True)
class View:
    scale: float          # pixels per world unit
    origin: tuple         # pixel position of world (0,0)

    def px(self, xy) -> tuple[int, int]:
        return (int(round(self.origin[0] + xy[0] * self.scale)),
                int(round(self.origin[1] + xy[1] * self.scale)))

    def len(self, v: float) -> int:
        return max(1, int(round(v * self.scale)))


def camera_view(camera: str, size: tuple[int, int], states: dict[str, HandState]) -> View:
    """ego: the world square centred in the image; wrist_<hand>: 2x zoom on that hand's
    mean position (a head-fixed approximation of a wrist camera, cheap and deterministic)."""
    w, h = size
    s = float(min(w, h))
    if camera == "ego":
        return View(s, (w / 2 - 0.5 * s, h / 2 - 0.5 * s))
    if camera.startswith("wrist_") and camera[6:] in states:
        c = states[camera[6:]].hand_xy.mean(axis=0) - np.array([0.0, 0.1])
        return View(2 * s, (w / 2 - c[0] * 2 * s, h / 2 - c[1] * 2 * s))
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


def background(scene: str, w: int, h: int) -> np.ndarray:
    """Scene-dependent static backdrop (wall + table + texture), cached per size."""
    return _background_cached(scene_style(scene), stable_hash(scene), int(w), int(h))


_SKIN = (224, 172, 140)
_SKIN_DARK = (150, 100, 75)


def draw_object(img, shape, xy, scale, rgb, view: View) -> None:
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
    elif shape == "cup":      # a mug wider than the fist that holds it: body, rim, a handle on the right
        hw, top, bottom = int(3.0 * r), c[1] - int(1.6 * r), c[1] + int(2.6 * r)
        cv2.ellipse(img, (c[0] + hw, c[1] + r // 2), (r, int(1.2 * r)), 0, 0, 360, dark, max(2, r // 3), aa)
        cv2.rectangle(img, (c[0] - hw, top), (c[0] + hw, bottom), rgb, -1)
        cv2.ellipse(img, (c[0], top), (hw, max(1, r // 2)), 0, 0, 360, dark, -1, aa)
    elif shape == "bag":
        cv2.ellipse(img, (c[0], c[1] + r // 2), (int(1.4 * r), r), 0, 180, 360, dark, max(2, r // 4), aa)
        cv2.rectangle(img, (c[0] - 2 * r, c[1] + r // 2), (c[0] + 2 * r, c[1] + 4 * r), rgb, -1)
    else:
        raise ValueError(f"unknown object shape {shape!r}")


SUPPORT_PAD_RGB = (105, 95, 88)     # what a support hand presses on (drawn under its palm)


def draw_support_pad(img, xy, view: View) -> None:
    """The surface a supporting hand steadies itself on: a block a little wider than the palm, so its
    edges show around the palm pressed on it (the camera sees the contact the glove feels)."""
    c = np.asarray(xy, dtype=np.float64)
    hw, hh = PALM_W * 0.75, PALM_H * 0.7
    p0, p1 = view.px(c - [hw, hh]), view.px(c + [hw, hh])
    cv2.rectangle(img, p0, p1, SUPPORT_PAD_RGB, -1)
    cv2.rectangle(img, p0, p1, tuple(int(v * 0.6) for v in SUPPORT_PAD_RGB), 2)


def draw_hand(img, hand: str, xy, closure, view: View) -> None:
    """Palm rectangle + five jointed finger polylines, closure-driven."""
    c = np.asarray(xy, dtype=np.float64)
    hw, hh = PALM_W / 2, PALM_H / 2
    palm = np.array([[-hw, -hh], [hw, -hh], [hw * 1.05, hh], [-hw * 1.05, hh]]) + c
    poly = np.array([view.px(p) for p in palm], dtype=np.int32)
    # forearm first so the palm covers its end
    cv2.line(img, view.px(c + [0, hh]), view.px(c + [0, hh + 0.25]), _SKIN_DARK, view.len(0.11), cv2.LINE_AA)
    cv2.fillConvexPoly(img, poly, _SKIN, cv2.LINE_AA)
    cv2.polylines(img, [poly], True, _SKIN_DARK, 2, cv2.LINE_AA)
    for name, pts in finger_points(np.asarray(closure, np.float64), hand).items():
        width = view.len(0.026 if name != "little" else 0.021)
        p = np.array([view.px(q) for q in pts + c], dtype=np.int32)
        cv2.polylines(img, [p], False, _SKIN_DARK, width + 3, cv2.LINE_AA)
        cv2.polylines(img, [p], False, _SKIN, width, cv2.LINE_AA)
