"""What a glove's value block says about its counts: the one owner of the rules every other module reads.

A layout's `value` ({"convention", "max"}, optional "step", "press") and a calibration (`convention`,
`max_value`) say:

- direction: "direct" counts rise with pressure, "inverted" counts fall with it (OpenTouch: 3072 = no load);
- a raw-count glove: full scale above 1 (an ADC's counts, either direction): its cells rest far from the
  no-pressure end with per-cell offsets, so it needs a rest of its own (the raw-count default,
  htdata.glove.normaliseconfig.RAW_COUNT_DEFAULTS); a glove in [0, 1] is read as given;
- sensitivity: `press`, the least rise above rest (raw units) that is a press, which decides contact
  (htdata.glove.contact); without it DEFAULT_PRESS_SHARE of full scale, a knit glove's 15 of 1023 counts.
  It is the glove's to declare: on the real knit glove's recordings a level 5% off takes the worst contact-share
  error of a hand that steadies an object from 0.08 to 0.13-0.18 (`htdata bench --only realglove`), and neither
  the glove's rest spread nor its press range pins it that closely (docs/INGEST.md, "Contact on a less sensitive glove").

Rules that assume "a press raises a cell" (rest level, wander, moving cells, health, validate's rest check)
turn counts toward pressure here first, so an inverted glove gets the same answers as a direct one.
"""

from __future__ import annotations

import numpy as np

CONVENTIONS = ("inverted", "direct")
# the least rise above rest that is a press, as a share of full scale, where `value.press` is not given: 15 of
# 1023 counts on a knit glove, whose rest wanders by several counts over a clip while a grip presses its cells
# by 15 to ~460 counts
DEFAULT_PRESS_SHARE = 0.015


def is_inverted(convention: str | None) -> bool:
    """True when the glove's counts fall with pressure."""
    return convention == "inverted"


def convention_name(inverted: bool) -> str:
    """The `value.convention` of a glove whose counts fall with pressure (`inverted`) or rise with it."""
    return CONVENTIONS[0] if inverted else CONVENTIONS[1]


def full_scale(value: dict | None) -> float:
    """A layout value block's full scale: its `max` (1.0 where the block or its max is missing: a glove in [0, 1])."""
    return float((value or {}).get("max") or 1.0)


def is_raw_count(max_value) -> bool:
    """True for a raw-count glove (full scale above 1, either direction)."""
    return float(max_value) > 1.0


def toward_pressure(raw, convention: str | None, top) -> np.ndarray:
    """Raw units turned so they rise with pressure (float32): `top - raw` for an inverted glove, else `raw`."""
    raw = np.asarray(raw, np.float32)
    return np.float32(top) - raw if is_inverted(convention) else raw


def pressure_share(raw, convention: str | None, top) -> np.ndarray:
    """Raw units -> share of full scale in the pressure direction (float32, NaN kept)."""
    return toward_pressure(raw, convention, top) / np.float32(top)


def least_pressure(lo, hi, convention: str | None):
    """Of a cell's lowest and highest raw reading, the one with the least pressure (its rest side)."""
    return hi if is_inverted(convention) else lo


def press_share(value: dict | None, top=None) -> float:
    """The least rise above rest that is a press, as a share of full scale `top` (default: `value["max"]`):
    `value["press"] / top` where the layout declares it, else DEFAULT_PRESS_SHARE."""
    value = value or {}
    if value.get("press") is None:
        return DEFAULT_PRESS_SHARE
    return float(value["press"]) / float(top if top is not None else value["max"])
