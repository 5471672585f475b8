"""The normaliser's settings (`NormaliseConfig`): which baseline, floor, scale and clip turn one glove
layout's raw units into contact in [0,1], checked once (`validate`); the rules and defaults they follow.

htdata/glove/normalise.py applies a config (`Normaliser`); htdata/glove/normalisesettings.py gives
each layout its config from a pipeline.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from htdata.errors import ConfigError
from htdata.glove.glovevalue import CONVENTIONS, is_raw_count

BASELINES = ("none", "first_frame", "rest_window", "quietest", "percentile", "drift", "shift")
# baselines fitted on the whole episode (`fit_episode`), not on its first chunk
EPISODE_BASELINES = ("quietest", "percentile", "drift", "shift")
# "shift": the glove's own rest comes from its taxel calibration file (a rest reference pooled over the
# glove's recordings: htdata.glove.restreference); per episode only the common-mode shift is fitted, so a
# grip held through a whole recording stays pressed (issue 43). Needs taxel_calibration.
# A raw-count glove (value.max > 1, counts rising or falling with pressure) without a [normalise.<id>] table: "none" would read its rest level
# (~557 of 1023 on a knit glove) as 0.55 pressure everywhere (issue 27). Each cell's own rest (its 10th percentile per
# minute: a press only raises a cell) and a per-cell noise floor hold a grip a real glove's mean level cannot see
# (issue 34). Measured in `make bench`, "real glove" (docs/INGEST.md).
RAW_COUNT_DEFAULTS = {"baseline": "drift", "baseline_percentile": 10.0, "drift_window_s": 60.0, "noise_k": 5.0}
NOISE_K_BASELINES = ("rest_window", *EPISODE_BASELINES)
KNOTTED_BASELINES = ("drift", "shift")   # NormaliseConfig.knotted   # the baselines a noise_k floor is measured against


def has_noise_floor(noise_k: float, noise_floor: float) -> bool:
    """The one test of whether a calibration subtracts a noise floor: k x the rest spread, or a constant one.

    Args:
        noise_k: the config's (or a calibration record's) noise_k.
        noise_floor: its constant floor, in unit values.

    Returns:
        True when a floor is subtracted.
    """
    return noise_k > 0 or noise_floor > 0


@dataclass
class NormaliseConfig:
    """How one glove layout's raw units become contact in [0,1] (htdata/glove/normalise.py's formula).

    Args:
        convention: "direct" (more pressure reads higher) or "inverted" (glovevalue.CONVENTIONS).
        max_value: the full-scale raw value (the layout's value.max), > 0.
        baseline: one of BASELINES: how the per-taxel rest is found ("none": no baseline).
        rest_frames: frames averaged (median) for baseline="rest_window".
        clip: clip values to [0,1] (False: a finite live value outside it is an error).
        scale: multiplier after the baseline and floor.
        noise_floor: a constant floor in unit values (after the baseline), < 1.
        noise_k: + k x the robust spread of the rest, per taxel (needs a baseline with a rest: NOISE_K_BASELINES).
        rest_seconds: span length of baseline="quietest" (and of the noise spread of the episode baselines).
        baseline_percentile: baseline="percentile": the per-taxel percentile over the episode.
        drift_window_s: baseline="drift": the window of the running rest level.
        shift_window_s: baseline="shift": the window of the common-mode shift (a median over the glove's
            cells: a short window is steady and follows slow wander).
        taxel_calibration: a per-glove calibration measured once: an .npz with per-taxel `offset` (rest, raw
            units) and `gain` (multiplier after the offset, 1 = nominal: a taxel twice as sensitive has 0.5),
            each (H,W). The pipeline resolves the path (NormaliseSettings.normalise_for); the arrays travel in
            each episode record's calibration_fit.
        taxel_calibration_sha256: that file's sha256, filled in with the path.
    """
    convention: str = "direct"
    max_value: float = 1.0
    baseline: str = "none"
    rest_frames: int = 10
    clip: bool = True
    scale: float = 1.0
    noise_floor: float = 0.0
    noise_k: float = 0.0
    rest_seconds: float = 1.0
    baseline_percentile: float = 5.0
    drift_window_s: float = 30.0
    shift_window_s: float = 2.0
    taxel_calibration: str = ""
    taxel_calibration_sha256: str = ""

    @property
    def per_episode(self) -> bool:
        """True when the baseline is fitted on the whole episode (`Normaliser.fit_episode`)."""
        return self.baseline in EPISODE_BASELINES

    @property
    def knotted(self) -> bool:
        """True when the baseline moves along the episode: knots (K,H,W) at row positions, so `apply` needs
        the raw rows' positions (baseline "drift", and "shift" whose common-mode shift follows the glove)."""
        return self.baseline in KNOTTED_BASELINES

    @property
    def rest_from_glove(self) -> bool:
        """True when the rest is the glove's reference (a taxel calibration file) plus each recording's
        common-mode shift: baseline "shift" (htdata.glove.restreference, htdata.glove.pooledrest)."""
        return self.baseline == "shift"

    @property
    def has_noise_floor(self) -> bool:
        """True when a floor is subtracted (noise_k or noise_floor > 0: `has_noise_floor`)."""
        return has_noise_floor(self.noise_k, self.noise_floor)

    @property
    def raw_counts(self) -> bool:
        """True for a raw-count glove (full scale above 1: glovevalue.is_raw_count), which needs a rest of its own."""
        return is_raw_count(self.max_value)

    @property
    def subtracts_rest(self) -> bool:
        """True when the normaliser takes a rest level off the counts (a baseline, or a per-glove calibration
        file); False for baseline "none" without one, where a raw-count glove's rest reads as pressure
        (htdata.glove.restlevel's warning, validate's rest-level check)."""
        return self.baseline != "none" or bool(self.taxel_calibration_sha256)

    @property
    def fits(self) -> bool:
        """True when the calibration has per-episode fitted arrays (baseline / noise floor)."""
        return self.baseline != "none" or self.noise_k > 0 or bool(self.taxel_calibration_sha256)

    def validate(self, where: str = "normalise") -> "NormaliseConfig":
        """Check every field and their combinations (noise_k needs a baseline with a rest, "shift" a file).

        Args:
            where: names the table in errors.

        Returns:
            self, so a config can be checked where it is built.

        Raises:
            ConfigError: the first field out of its range, naming it and the value.
        """
        if self.convention not in CONVENTIONS:
            raise ConfigError(f"{where}: convention must be one of {CONVENTIONS}, got {self.convention!r}")
        if not (isinstance(self.max_value, (int, float)) and np.isfinite(self.max_value)
                and self.max_value > 0):
            raise ConfigError(f"{where}: max_value must be a finite number > 0, got {self.max_value!r}")
        if self.baseline not in BASELINES:
            raise ConfigError(f"{where}: baseline must be one of {BASELINES}, got {self.baseline!r}")
        if not isinstance(self.rest_frames, int) or self.rest_frames < 1:
            raise ConfigError(f"{where}: rest_frames must be an integer >= 1, got {self.rest_frames!r}")
        if not (isinstance(self.scale, (int, float)) and np.isfinite(self.scale) and self.scale > 0):
            raise ConfigError(f"{where}: scale must be a finite number > 0, got {self.scale!r}")
        if not isinstance(self.clip, bool):
            raise ConfigError(f"{where}: clip must be true or false, got {self.clip!r}")
        for name in ("noise_floor", "noise_k"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
                    and 0 <= value):
                raise ConfigError(f"{where}: {name} must be a finite number >= 0, got {value!r}")
        if self.noise_floor >= 1:
            raise ConfigError(f"{where}: noise_floor must be < 1 (unit values), got {self.noise_floor!r}")
        if self.baseline == "shift" and not self.taxel_calibration and not self.taxel_calibration_sha256:
            raise ConfigError(f"{where}: baseline = \"shift\" fits only a recording's common-mode shift from the "
                              f"glove's rest reference: set taxel_calibration to one (htdata layouts rest writes it)")
        if self.noise_k > 0 and self.baseline not in NOISE_K_BASELINES:
            raise ConfigError(f"{where}: noise_k needs baseline = \"rest_window\" (the floor is k x the rest "
                              f"window's spread) or one of {EPISODE_BASELINES}, got baseline = {self.baseline!r}")
        for name, lo, hi in (("rest_seconds", 0.0, None), ("baseline_percentile", 0.0, 100.0),
                             ("drift_window_s", 0.0, None), ("shift_window_s", 0.0, None)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
                    and value > lo and (hi is None or value <= hi)):
                raise ConfigError(f"{where}: {name} must be a finite number > {lo:g}"
                                  f"{'' if hi is None else f' and <= {hi:g}'}, got {value!r}")
        return self

    @classmethod
    def from_record(cls, entry: dict | None) -> "NormaliseConfig":
        """The config a manifest calibration entry records, read as written (not checked: `validate` does that),
        so validate/, inspect/ and curate/ ask it (`raw_counts`, `subtracts_rest`) instead of the entry's keys.

        Args:
            entry: a manifest `calibrations` entry; None or {} for an episode hand that names none.

        Returns:
            Its NormaliseConfig: the fields it holds, the others at their defaults (its other keys, such as
            layout, from and revision, are not settings and are left out).
        """
        fields = cls.__dataclass_fields__
        return cls(**{k: v for k, v in (entry or {}).items() if k in fields})

    @classmethod
    def from_layout_value(cls, value: dict) -> "NormaliseConfig":
        """Default config from a layout's `value` block: RAW_COUNT_DEFAULTS for raw counts (max > 1 in either
        direction: the values rest far from the no-pressure end), else no baseline.

        Args:
            value: the layout's value block ({"convention", "max", ...}).

        Returns:
            The checked config.
        """
        extra = RAW_COUNT_DEFAULTS if is_raw_count(value["max"]) else {}
        return cls(convention=value["convention"], max_value=float(value["max"]), **extra).validate()

    def to_dict(self) -> dict:
        """The settings; the activity-baseline fields only when they differ from their defaults, so the
        calibration ids (a hash of this) of pipelines written before they existed stay the same.

        Returns:
            Field -> value, without the calibration file's path (its sha256 is its identity).
        """
        d = asdict(self)
        del d["taxel_calibration"]        # where the file was is not its identity: its sha256 is
        for name in ("rest_seconds", "baseline_percentile", "drift_window_s", "shift_window_s",
                     "taxel_calibration_sha256"):
            if d[name] == type(self).__dataclass_fields__[name].default:
                del d[name]
        return d
