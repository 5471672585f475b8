"""When a glove hand is "in contact": one rule per episode hand, from its calibration.

    calibrated  (the calibration has a noise floor: noise_k > 0 or noise_floor > 0)
                a taxel is in contact when it is pressed: more than the glove's press
                level above its rest (its baseline: `value.press` raw units, default
                DEFAULT_PRESS_SHARE of full scale, htdata.glove.glovevalue), and more than
                LEVEL_STEPS quantisation steps (`value.step / max`, 0 when the layout gives
                no step) above its noise floor. Values are floor-subtracted, so with the
                taxel's floor f: value > max(2 steps, press - f) (x the calibration's scale);
                a frame is in contact when at least max(MIN_AREA_TAXELS, MIN_AREA_SHARE x the
                hand's live taxels) taxels are (3 on a 169-taxel glove, 7 on a 692-taxel one).
    threshold   (no noise floor: the clean-world gloves, and the old rule on request)
                a taxel is in contact above THRESHOLD (0.02) and one taxel is enough.

Why: on a raw-count glove whose rest level wanders, a fixed 0.02 on the
maximum taxel counts a hand that only steadies an object as in contact in
half of its frames from a handful of flickering taxels. A floor fitted on
the glove's own noise says what "above rest" means for each taxel, and an
area of a few taxels says what a touch is (a single taxel crossing its
floor now and then is noise). The floor says where rest ends, not where a
touch begins: a real knit glove's hand that only steadies an object has
dozens of cells 5-15 counts above rest in most frames, while a press moves a
cell by 15 to ~460 counts (the real knit glove's recordings, issue 34: `htdata bench --real-glove DIR`), so a touch is a
rise of the press level above rest (when the per-taxel floor is known; without it,
the floor alone). A glove less sensitive than a knit glove declares its own level (`value.press`). Without a floor there is nothing glove-specific
to go by, so the old threshold stays (the sample corpus's gloves have none:
their numbers are unchanged).

The same rule serves `htdata stats` (contact fraction, region contact),
`htdata trim --idle`, the dataset card and the preview's frame choice;
`htdata trim --idle --min-contact X` still applies the old per-taxel
threshold X to the frame maxima.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from htdata.glove.glovevalue import press_share
from htdata.glove.normaliseconfig import has_noise_floor

THRESHOLD = 0.02           # the old rule: a taxel above this is contact (validate's contact threshold)
MIN_AREA_TAXELS = 3        # calibrated rule: taxels above their floor for a frame to be in contact
# calibrated rule: steps above the floor. Measured on the sample raw-count glove (1-count steps, noise_k = 3):
# resting frames have a median of 9 (quietest) / 5 (drift) taxels just above their floor (slow creep and
# rounding move a count or two), 0 more than 2 steps above it (90th percentile 1); touched frames have >= 30.
LEVEL_STEPS = 2
# ... and in 0.18% of resting frames 3 scattered taxels are above that at once (none reach 6): a big glove
# needs a bigger area, or one stray frame keeps a whole idle tail in `trim --idle`.
MIN_AREA_SHARE = 0.01
RULE_VERSION = 3           # part of the stats cache key (3: the press level is the layout's value.press)


@dataclass(frozen=True)
class ContactRule:
    basis: str             # "calibrated" or "threshold"
    level: float           # a taxel is in contact when its normalised value is > level
    min_taxels: int        # a hand is in contact in a frame when at least this many taxels are
    press: float = 0.0     # calibrated: ... and > press - its floor (value units; 0: the floor alone)

    def levels(self, floor: np.ndarray | None = None) -> np.ndarray | float:
        """The level each taxel must exceed: `level`, raised to press - floor where the (L,) per-taxel noise floor
        (in value units: the calibration's floor x scale) is known."""
        if not self.press or floor is None:
            return self.level
        return np.maximum(np.float32(self.level), np.float32(self.press) - np.asarray(floor, np.float32))

    def taxels(self, x: np.ndarray, floor: np.ndarray | None = None) -> np.ndarray:
        """(T, L) normalised values -> (T, L) bool taxel contact (`floor`: see `levels`)."""
        return np.asarray(x) > self.levels(floor)

    def frames(self, x: np.ndarray, floor: np.ndarray | None = None) -> np.ndarray:
        """(T, L) normalised values -> (T,) bool: the hand is in contact."""
        return self.taxels(x, floor).sum(axis=1) >= self.min_taxels

    def describe(self) -> str:
        if self.basis == "calibrated":
            pressed = f"pressed more than {self.press:.4g} of full scale above rest (value.press) and " if self.press else ""
            return (f"at least {self.min_taxels} taxels {pressed}more than {LEVEL_STEPS} quantisation steps above "
                    f"their noise floor (value > {self.level:.4g})")
        return f"any taxel > {self.level:g}" if self.min_taxels == 1 else \
            f"at least {self.min_taxels} taxels > {self.level:g}"

    def to_dict(self) -> dict:
        return asdict(self)


OLD_RULE = ContactRule("threshold", THRESHOLD, 1)


def min_area(live_taxels: int) -> int:
    """Taxels the calibrated rule needs in contact at once, for a glove hand of `live_taxels` taxels."""
    return max(MIN_AREA_TAXELS, int(np.ceil(MIN_AREA_SHARE * live_taxels)))


def rule_for(calibration: dict | None, layout_value: dict | None = None, live_taxels: int = 0) -> ContactRule:
    """The contact rule of an episode hand from its manifest calibration entry (None: none recorded), its
    layout's value block (the quantisation step, the press level) and its number of live taxels."""
    if calibration and has_noise_floor(float(calibration.get("noise_k", 0) or 0),
                                       float(calibration.get("noise_floor", 0) or 0)):
        step = float((layout_value or {}).get("step") or 0.0)
        top = float(calibration.get("max_value") or (layout_value or {}).get("max") or 1.0)
        scale = float(calibration.get("scale") or 1.0)
        return ContactRule("calibrated", round(LEVEL_STEPS * step / top * scale, 9), min_area(live_taxels),
                           round(press_share(layout_value, top) * scale, 9))
    return OLD_RULE


def episode_rule(manifest: dict, episode: dict, hand: str, layout=None) -> ContactRule:
    """`rule_for` the calibration the episode record names for `hand` (layout: its parsed Layout)."""
    cal = (episode.get("calibration") or {}).get(hand)
    return rule_for(manifest.get("calibrations", {}).get(cal) if cal else None,
                    getattr(layout, "value", None), int(layout.live_mask.sum()) if layout is not None else 0)
