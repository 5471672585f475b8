"""The tactile map codec, chosen by a rule instead of written by hand.

RULE: among the codecs the dataset's EXR member can store (half or float
pixels, at the pipeline's `[tactile] compression`, every one of which is
lossless), take the smallest whose max error on [0,1] maps is below half of
one quantisation step of EVERY glove of the dataset, in map units. A value
then rounds back to its source level, so the map keeps every level the
glove delivered.

A glove's step in map units is its layout's `value.step` (raw units: 1 for
integer firmware counts such as OpenTouch's 0..3072, 1/255 for
TouchAnything's values computed from uint8 bytes) divided by the
normalisation's `max_value` and multiplied by its `scale` (a baseline or a
noise floor shifts the levels but keeps their spacing). A layout that
states no step could have any resolution: only an exact codec keeps its
levels.

Per dataset, the strictest glove wins (not per glove): the manifest records
one codec, `htdata validate` and the readers check one pixel type, and
append / merge compare one setting. The cost is bytes: TouchAnything maps
stored next to OpenTouch ones are float (the bench's codec table gives the
sizes). An existing dataset keeps its codec on append (`resolve_codec` with
`existing`); the reason then says whether it keeps the new gloves' levels.

Two callers share `pick_codec`: the ingest, with the analytic max errors
below (`resolve_codec`, through the pipeline's `[codec]` section,
htdata/glove/codecsettings.py; htdata.ingest.plan.resolve_sources resolves it
once per run for the run's gloves), and the bench, with the errors and sizes measured on
real maps (htdata/benchmarks/codecs.py); tests/format/test_codec.py checks that
both pick the same codec on the sample corpus.
"""

from __future__ import annotations

from dataclasses import dataclass

from htdata.errors import ConfigError
from htdata.glove.layouts import Layout
from htdata.glove.normalisesettings import NormaliseSettings

SETTINGS = ("auto", "exr_half", "exr_float")      # pipeline [codec] tactile
PIXEL_TYPES = ("half", "float")
# max |decoded - map| over maps in [0,1], per EXR pixel type: float16 rounds to nearest with
# spacing 2**-11 just below 1.0 (htdata/format/tactilecodec.py); float32 maps stored as float32 are exact.
ANALYTIC_MAX_ERROR = {"half": 2.0 ** -12, "float": 0.0}
# Smallest first at one compression: half stores 2 bytes per pixel, float 4 (checked on the
# sample corpus's maps by tests/format/test_codec.py, measured by the bench's codec table).
SIZE_ORDER = ("half", "float")
RULE = ("smallest EXR codec (at the pipeline's compression) whose max error is below half of every "
        "glove's quantisation step in map units (value.step / max_value x scale); a glove without a "
        "stated step needs an exact codec")


def codec_name(pixel_type: str, compression: str) -> str:
    """"exr_<pixel type>_<compression>", the name the bench's codec table uses."""
    if pixel_type not in PIXEL_TYPES:
        raise ValueError(f"unknown EXR pixel type {pixel_type!r}; known: {PIXEL_TYPES}")
    return f"exr_{pixel_type}_{compression}"


def parse_codec_name(name: str) -> tuple[str, str] | None:
    """(pixel type, compression) of an EXR codec name, None for anything else (png16, ...)."""
    parts = name.split("_", 2)
    if len(parts) != 3 or parts[0] != "exr" or parts[1] not in PIXEL_TYPES:
        return None
    return parts[1], parts[2]


@dataclass(frozen=True)
class GloveStep:
    """One glove's quantisation step in map units (None: the layout states none) and where it comes from."""
    layout_id: str
    step: float | None
    source: str

    def keeps_levels(self, max_error: float) -> bool:
        return max_error == 0.0 if self.step is None else max_error < self.step / 2.0


def glove_step(layout, normalise=None) -> GloveStep:
    """The step of `layout` (a Layout) under `normalise` (a NormaliseConfig; default: the layout's value block)."""
    value = layout.value
    raw = value.get("step")
    if raw is None:
        return GloveStep(layout.layout_id, None, "the layout's value block states no step")
    max_value = float(normalise.max_value) if normalise is not None else float(value["max"])
    scale = float(normalise.scale) if normalise is not None else 1.0
    return GloveStep(layout.layout_id, float(raw) / max_value * scale,
                     f"value.step {float(raw):.6g} / max_value {max_value:g} x scale {scale:g}")


def strictest(gloves: list[GloveStep]) -> GloveStep | None:
    """The glove that constrains the codec most (a glove without a step first, then the finest step)."""
    if not gloves:
        return None
    return min(gloves, key=lambda g: (g.step is not None, g.step or 0.0, g.layout_id))


def pick_codec(gloves: list[GloveStep], rows: list[dict]) -> tuple[dict | None, str]:
    """(the row the RULE picks, or None, and why) among `rows` ({"codec", "max_error"[, "bytes_per_frame"]}).

    Rows with "bytes_per_frame" compete on it; without it, on their order
    (smallest first). Only EXR rows (what the dataset member can store) compete.
    """
    storable = [r for r in rows if parse_codec_name(r["codec"]) is not None]
    if all("bytes_per_frame" in r for r in storable):
        storable = sorted(storable, key=lambda r: r["bytes_per_frame"])
    keeping = [r for r in storable if all(g.keeps_levels(r["max_error"]) for g in gloves)]
    tight = strictest(gloves)
    if tight is None:
        return (storable[0] if storable else None), "no glove constrains the codec: the smallest one"
    bound = "max error 0" if tight.step is None else f"max error < {tight.step / 2:.3g} (half of {tight.step:.3g})"
    where = f"strictest glove {tight.layout_id} ({tight.source}) needs {bound}"
    if not keeping:
        return None, f"{where}; no storable codec meets it"
    chosen = keeping[0]
    skipped = [r["codec"] for r in storable[:storable.index(chosen)]]
    also = f"; smaller {', '.join(skipped)} would lose levels" if skipped else ""
    return chosen, f"{where}: {chosen['codec']} has max error {chosen['max_error']:.3g}{also}"


@dataclass(frozen=True)
class CodecChoice:
    """The dataset's tactile codec and why (the manifest's "codec" -> "choice"; its pixel type also in "tactile")."""
    pixel_type: str
    compression: str
    chosen_by: str          # "rule" (setting auto), "pipeline" (explicit setting), "dataset" (kept on append)
    reason: str

    @property
    def codec(self) -> str:
        return codec_name(self.pixel_type, self.compression)

    def info(self) -> dict:
        """The manifest's "codec" -> "choice" (and the pipeline's resolved [codec] choice)."""
        return {"codec": self.codec, "pixel_type": self.pixel_type, "compression": self.compression,
                "chosen_by": self.chosen_by, "rule": RULE, "reason": self.reason}

    @classmethod
    def from_info(cls, info: dict) -> "CodecChoice":
        return cls(info["pixel_type"], info["compression"], info["chosen_by"], info["reason"])


def codec_block(base: dict, choice: CodecChoice) -> dict:
    """The manifest's "codec" block: `base` (codec.DEFAULT_CODEC_INFO + settings) with the choice applied.

    The pixel type goes into "tactile" (what append and merge compare); the
    codec name, who chose it and why go into "choice" (descriptive).
    """
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
    out["tactile"]["pixel_type"] = choice.pixel_type
    out["tactile"]["compression"] = choice.compression
    out["choice"] = choice.info()
    return out


def analytic_rows(compression: str) -> list[dict]:
    """The storable candidates at `compression`, smallest first, with their analytic max errors."""
    return [{"codec": codec_name(p, compression), "max_error": ANALYTIC_MAX_ERROR[p]} for p in SIZE_ORDER]


def resolve_codec(setting: str, compression: str, gloves: list[GloveStep],
                  existing: dict | None = None) -> CodecChoice:
    """The codec a dataset with `gloves` gets under pipeline `setting` ("auto" or an explicit "exr_*").

    `existing`: the manifest "codec" -> "tactile" block of the dataset being
    appended to; with "auto" its pixel type is kept (one codec per dataset).
    """
    if setting not in SETTINGS:
        raise ConfigError(f"[codec] tactile must be one of {SETTINGS}, got {setting!r}")
    rows = analytic_rows(compression)
    if setting != "auto":
        pixel = setting.split("_", 1)[1]
        error = ANALYTIC_MAX_ERROR[pixel]
        lost = sorted(g.layout_id for g in gloves if not g.keeps_levels(error))
        return CodecChoice(pixel, compression, "pipeline",
                           f"set by the pipeline ([codec] tactile = {setting!r}); max error {error:.3g}; "
                           f"levels NOT kept for: {', '.join(lost) or 'none'}")
    row, why = pick_codec(gloves, rows)
    picked = parse_codec_name(row["codec"])[0] if row is not None else None
    kept = existing.get("pixel_type") if existing is not None else None
    if kept in PIXEL_TYPES and kept != picked:
        # The same choice as the first ingest whenever the rule agrees: re-runs keep their fingerprints.
        lost = sorted(g.layout_id for g in gloves if not g.keeps_levels(ANALYTIC_MAX_ERROR[kept]))
        return CodecChoice(kept, compression, "dataset",
                           f"the dataset's codec is kept on append (one codec per dataset; the rule would pick "
                           f"{picked and codec_name(picked, compression)}); levels NOT kept for: "
                           f"{', '.join(lost) or 'none'}")
    if row is None:
        raise ConfigError(f"no tactile codec keeps every glove's levels: {why}")
    return CodecChoice(picked, compression, "rule", why)


def dataset_gloves(pairs: list[tuple[NormaliseSettings, Layout]]) -> list[GloveStep]:
    """One GloveStep per distinct (layout, normalisation) in `pairs` of (NormaliseSettings, Layout)."""
    out: dict[tuple, GloveStep] = {}
    for normalising, layout in pairs:
        g = glove_step(layout, normalising.normalise_for(layout))
        out.setdefault((g.layout_id, g.step), g)
    return [out[k] for k in sorted(out, key=lambda k: (k[0], k[1] or 0.0))]
