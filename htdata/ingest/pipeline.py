"""Ingest pipelines as data: `pipelines/*.toml` -> PipelineConfig.

A pipeline says how one source format becomes canonical samples: which
adapter reads it (and its params), which glove layout each hand uses, how
glove units are normalised (per layout), the sync tolerance and clock lag
(`[sync] lag`: htdata/source/lag.py), RGB and tactile encoding, and the shard
size. `PipelineConfig` holds one object per section; the sections read by code
below the ingest live beside that code, each with its keys' parsing and checks
([sync] htdata/source/syncsettings.py, [rgb] htdata/source/rgbsettings.py,
[tactile] htdata/format/tactilesettings.py, [codec] htdata/glove/codecsettings.py;
normalising gets htdata/glove/normalisesettings.py's NormaliseSettings), and
that code never sees the pipeline itself. Files are checked three times: against
`schemas/pipeline.schema.json` (unknown keys are errors, named with the file),
for non-finite numbers (TOML allows `nan`/`inf`, JSON Schema's "number"
accepts them: `max_skew_ms = nan` would fail every episode later), and by
`validate()` (cross-field rules the schema cannot express, and
`[adapter.params]` against the params the adapter declares).

Settings can be overridden from the command line without copying the file
(`htdata ingest --set adapter.params.annotations=labels.csv`):
`with_overrides` applies dotted keys to the TOML content and validates the
result like a file; the effective settings are what the manifest records.

Out-of-range raw values: `[normalise] out_of_range = "clip" | "drop_frame" |
"fail"` (pipeline-wide; default "clip") and `out_of_range_warn_share`
(default 0.01: with "clip", a hand whose share of out-of-range frames in an
episode exceeds 1% gets a warning note). These two keys sit beside the
per-layout tables, so no layout may be named like them. Range = [0,
max_value] in raw units of the layout's normalise config.

Example (pipelines/opentouch.toml):

    name = "opentouch"
    [adapter]
    name = "opentouch"
    [adapter.params]
    channel_order = "bgr"
    [normalise.opentouch_right_16x16]
    convention = "inverted"
    max_value = 3072
    [sync]
    max_skew_ms = 20
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from htdata._moved import moved_name
from htdata.errors import ConfigError
from htdata.format.mapstorage import MapStorage
from htdata.format.table import CodecSettings
from htdata.format.tactilesettings import TactileConfig
from htdata.glove.codecrule import CodecChoice
from htdata.glove.codecsettings import CodecConfig
from htdata.glove.layouts import nearest_hint
from htdata.glove.normaliseconfig import NormaliseConfig
from htdata.glove.normalisesettings import NormaliseSettings, add_glove_rests
from htdata.resources import PIPELINES_DIR, validate_json
from htdata.settings import apply_settings
from htdata.source.adapters import ADAPTERS
from htdata.source.adapters.params import check_declared_params
from htdata.source.rgbsettings import RgbConfig
from htdata.source.syncsettings import SyncConfig


@dataclass
class AdapterConfig:
    name: str
    params: dict = field(default_factory=dict)


OUT_OF_RANGE_POLICIES = ("clip", "drop_frame", "fail")
# keys of [normalise] that are not layout ids
NORMALISE_POLICY_KEYS = ("out_of_range", "out_of_range_warn_share")


@dataclass
class OutOfRangeConfig:
    """What to do with raw values outside [0, max_value] (counted per episode and hand whatever the policy)."""
    policy: str = "clip"          # clip: values clipped, counted, warning note above warn_share
    warn_share: float = 0.01      # share of an episode's frames (per hand) above which clip warns

    def validate(self, where: str) -> "OutOfRangeConfig":
        if self.policy not in OUT_OF_RANGE_POLICIES:
            raise ConfigError(f"{where}: normalise.out_of_range must be one of {OUT_OF_RANGE_POLICIES}, "
                              f"got {self.policy!r}")
        if not (isinstance(self.warn_share, (int, float)) and 0.0 <= self.warn_share <= 1.0):
            raise ConfigError(f"{where}: normalise.out_of_range_warn_share must be in [0, 1], got {self.warn_share!r}")
        return self

    def to_dict(self) -> dict:
        """Only non-default keys: a pipeline that never sets them keeps its to_dict() (and input fingerprints)."""
        d = {}
        if self.policy != "clip":
            d["out_of_range"] = self.policy
        if self.warn_share != 0.01:
            d["out_of_range_warn_share"] = self.warn_share
        return d


def non_finite_numbers(data, path: str = "") -> list[str]:
    """Dotted keys of every NaN/Inf float in a nested dict/list (TOML allows them, no setting wants them)."""
    if isinstance(data, float):
        return [] if math.isfinite(data) else [path or "<value>"]
    if isinstance(data, dict):
        return [k for key, v in data.items() for k in non_finite_numbers(v, f"{path}.{key}" if path else str(key))]
    if isinstance(data, list):
        return [k for i, v in enumerate(data) for k in non_finite_numbers(v, f"{path}[{i}]")]
    return []


def check_adapter_params(adapter: str, params: dict, where: str) -> None:
    """`params` against what the adapter declares (`PARAMS`): unknown keys and wrong types are errors."""

    if adapter not in ADAPTERS:
        raise ConfigError(f"{where}: unknown adapter {adapter!r}; known: {sorted(ADAPTERS)}")
    check_declared_params(adapter, tuple(getattr(ADAPTERS[adapter], "PARAMS", ())), params, where)


@dataclass
class ShardsConfig:
    samples_per_shard: int = 256


@dataclass
class PipelineConfig:
    name: str
    adapter: AdapterConfig
    # hand -> layout id, or path to a layout JSON relative to the pipeline file; overrides the source's
    # layout for that hand (resolved once per episode when the ingest plans: htdata.ingest.plan)
    layouts: dict[str, str] = field(default_factory=dict)
    normalise: dict[str, NormaliseConfig] = field(default_factory=dict)  # layout id -> config
    # layout id -> the keys its [normalise.<layout>] table sets; convention / max_value it leaves out come
    # from the layout's value block (so `--set normalise.L.noise_k=3` keeps the glove's units)
    normalise_given: dict[str, tuple[str, ...]] = field(default_factory=dict)
    out_of_range: OutOfRangeConfig = field(default_factory=OutOfRangeConfig)  # [normalise] out_of_range*
    sync: SyncConfig = field(default_factory=SyncConfig)
    rgb: RgbConfig = field(default_factory=RgbConfig)
    tactile: TactileConfig = field(default_factory=TactileConfig)
    codec: CodecConfig = field(default_factory=CodecConfig)
    shards: ShardsConfig = field(default_factory=ShardsConfig)
    description: str = ""
    # layout ids this pipeline configures ([normalise.<id>] / [layouts]) for sources whose recordings may not
    # use them, on purpose; any other id no recording of the source uses is an error (check_layout_names)
    shared_layouts: list[str] = field(default_factory=list)
    path: str = ""   # where it was loaded from (not part of the config's identity)
    settings: tuple[str, ...] = ()   # the --set items applied (with_overrides), to name them in errors
    # (what normalising reads of this pipeline, its NormaliseSettings): built once per state (normalise_settings)
    _normalising: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def validate(self) -> "PipelineConfig":
        where = self.path or f"pipeline {self.name!r}"
        d = self.to_dict()
        bad = non_finite_numbers(d)
        if bad:
            raise ConfigError(f"{where}: {', '.join(bad)} must be a finite number (NaN/Inf are not settings)")
        validate_json(d, "pipeline", where, ConfigError)
        for layout_id, cfg in self.normalise.items():
            cfg.validate(f"{where}: normalise.{layout_id}")
        self.out_of_range.validate(where)
        named = set(self.normalise) | {Path(v).stem if v.endswith(".json") else v for v in self.layouts.values()}
        for lid in self.shared_layouts:
            if lid not in named:
                raise ConfigError(f"{where}: shared_layouts lists {lid!r}, which no [normalise.<layout>] table or "
                                  f"[layouts] entry of this pipeline names{nearest_hint(lid, named)}")
        self.sync.validate(where)
        self.tactile.validate(where)
        check_adapter_params(self.adapter.name, self.adapter.params, where)
        return self

    def normalise_settings(self) -> NormaliseSettings:
        """What normalising needs of this pipeline (htdata.glove.normalisesettings), e.g. for `htdata renormalise`.

        One object while the fields it is made of stay as they are, so each layout's `[normalise]` is resolved
        once per run (NormaliseSettings.normalise_for), not once per episode; a change to those fields (a copy
        made by `with_glove_rests`, `--set`) makes a new one.
        """
        made_of = (self.name, self.path, self.normalise, self.normalise_given, self.layouts, self.shared_layouts,
                   self.settings, self.tactile.chunk_frames)
        key = repr(made_of)
        if self._normalising is None or self._normalising[0] != key:
            self._normalising = (key, NormaliseSettings(
                name=self.name, path=self.path, normalise=dict(self.normalise),
                normalise_given=dict(self.normalise_given), layouts=dict(self.layouts),
                shared_layouts=list(self.shared_layouts), settings=self.settings,
                fit_frames=self.tactile.chunk_frames))
        return self._normalising[1]

    def check_layout_names(self, used_ids: set[str], used_hands: set[str] | None, scope: str,
                           why: str = "") -> None:
        """Refuse layout ids this pipeline names that no recording of `scope` uses (NormaliseSettings)."""
        self.normalise_settings().check_layout_names(used_ids, used_hands, scope, why)

    def codec_choice(self) -> CodecChoice:
        """The resolved tactile codec (CodecConfig.resolved); the ingest resolves it first."""
        return self.codec.resolved(self.path or self.name)

    def with_maps(self, maps: MapStorage) -> "PipelineConfig":
        """A copy whose [tactile] maps is `maps` (an ingest resolves AUTO before its units run)."""
        cfg = copy.deepcopy(self)
        cfg.tactile.maps = maps
        cfg.tactile.validate(self.path or self.name)
        return cfg

    def with_codec_choice(self, choice: CodecChoice) -> "PipelineConfig":
        """A copy whose [codec] carries `choice` (a CodecChoice for this pipeline's compression)."""
        cfg = copy.deepcopy(self)
        cfg.codec = self.codec.with_choice(choice, self.tactile.compression, self.path or self.name)
        return cfg

    def with_glove_rests(self, references: dict[str, Path]) -> "PipelineConfig":
        """A copy with the pooled glove rest's `[normalise.<id>]` table for each layout id in `references`
        (htdata.glove.normalisesettings.glove_rest_config; htdata.ingest.gloverest)."""
        cfg = copy.deepcopy(self)
        cfg.normalise, cfg.normalise_given = add_glove_rests(self.normalise, self.normalise_given, references,
                                                             self.path or self.name)
        return cfg

    def codec_settings(self) -> CodecSettings:
        """What the encoders need (htdata.format.table.CodecSettings), from the resolved codec."""
        return CodecSettings(tactile_compression=self.tactile.compression, rgb_quality=self.rgb.quality,
                             tactile_pixel_type=self.codec_choice().pixel_type)

    def normalise_for(self, layout) -> NormaliseConfig:
        """The pipeline's config for this layout over the layout's own value block (NormaliseSettings)."""
        return self.normalise_settings().normalise_for(layout)

    def to_dict(self) -> dict:
        """Plain dict (the TOML content with defaults filled in); recorded in the manifest."""
        d = {
            "name": self.name,
            "adapter": {"name": self.adapter.name, "params": dict(self.adapter.params)},
            "layouts": dict(self.layouts),
            "normalise": {**{k: {kk: vv for kk, vv in _settings(v).items()
                                 if k not in self.normalise_given or kk in self.normalise_given[k]}
                              for k, v in self.normalise.items()}, **self.out_of_range.to_dict()},
            "sync": self.sync.to_dict(),
            "rgb": self.rgb.to_dict(),
            "tactile": self.tactile.to_dict(),
            "codec": self.codec.to_dict(),
            "shards": asdict(self.shards),
        }
        if self.description:
            d["description"] = self.description
        if self.shared_layouts:    # only when set: other pipelines keep their to_dict() (and fingerprints)
            d["shared_layouts"] = list(self.shared_layouts)
        return d

    @classmethod
    def from_dict(cls, data: dict, where: str = "pipeline") -> "PipelineConfig":
        bad = non_finite_numbers(data)
        if bad:
            raise ConfigError(f"{where}: {', '.join(bad)} must be a finite number (NaN/Inf are not settings)")
        validate_json(data, "pipeline", where, ConfigError)
        norm = dict(data.get("normalise", {}))
        policy = {k: norm.pop(k) for k in NORMALISE_POLICY_KEYS if k in norm}
        cfg = cls(
            name=data["name"],
            adapter=AdapterConfig(name=data["adapter"]["name"], params=dict(data["adapter"].get("params", {}))),
            layouts=dict(data.get("layouts", {})),
            normalise={k: NormaliseConfig(**v) for k, v in norm.items()},
            normalise_given={k: tuple(sorted(v)) for k, v in norm.items()},
            out_of_range=OutOfRangeConfig(policy=policy.get("out_of_range", "clip"),
                                          warn_share=float(policy.get("out_of_range_warn_share", 0.01))),
            sync=SyncConfig.from_dict(data.get("sync", {})),
            rgb=RgbConfig.from_dict(data.get("rgb", {})),
            tactile=TactileConfig.from_dict(data.get("tactile", {}), where),
            codec=CodecConfig.from_dict(data.get("codec", {})),
            shards=ShardsConfig(**data.get("shards", {})),
            description=data.get("description", ""),
            shared_layouts=list(data.get("shared_layouts", [])),
            path=where,
        )
        # TOML integers for float fields are fine; normalise them so to_dict() is stable.
        for n in cfg.normalise.values():
            n.max_value = float(n.max_value)
            n.scale = float(n.scale)
            n.noise_floor = float(n.noise_floor)
            n.noise_k = float(n.noise_k)
            for name in ("rest_seconds", "baseline_percentile", "drift_window_s", "shift_window_s"):
                if isinstance(getattr(n, name), int) and not isinstance(getattr(n, name), bool):
                    setattr(n, name, float(getattr(n, name)))
        return cfg.validate()

    def with_overrides(self, settings: list[str]) -> "PipelineConfig":
        """A copy with `dotted.key=value` settings applied (htdata/settings.py: values read as TOML, else text), validated."""
        d = self.to_dict()   # + [tactile] maps as set (to_dict leaves "stored" out: it would come back as "auto")
        data = apply_settings({**d, "tactile": {**d["tactile"], "maps": self.tactile.maps.value}}, settings)
        where = f"{self.path or self.name} (with --set {' '.join(settings)})"
        cfg = PipelineConfig.from_dict(data, where=where)
        cfg.path = self.path
        cfg.settings = tuple(self.settings) + tuple(settings)
        return cfg


def shipped_pipelines() -> list[str]:
    """Names of the pipelines that ship with htdata (`htdata pipelines list`)."""
    return sorted(p.stem for p in PIPELINES_DIR.glob("*.toml"))


def _settings(cfg: NormaliseConfig) -> dict:
    """A [normalise.<layout>] table as written: the calibration's settings + the calibration file's path."""
    d = cfg.to_dict()
    d.pop("taxel_calibration_sha256", None)          # filled in from the file, never written by hand
    if cfg.taxel_calibration:
        d["taxel_calibration"] = cfg.taxel_calibration
    return d


def resolve_pipeline_path(name_or_path: str | Path) -> Path:
    """A path to a .toml file, or a bare name looked up among the shipped pipelines.

    A directory is never a pipeline file: `--pipeline opentouch` in a folder holding a
    subfolder `opentouch/` (the raw data, typically) still means the shipped pipeline.
    """
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.is_file():
        return p
    return PIPELINES_DIR / f"{name_or_path}.toml"


def load_pipeline(name_or_path: str | Path) -> PipelineConfig:
    """Load and validate a pipeline TOML; errors name the file."""
    path = resolve_pipeline_path(name_or_path)
    if not path.is_file():
        raise FileNotFoundError(f"pipeline file not found: {name_or_path} (a .toml file, or a shipped pipeline "
                                f"name: {', '.join(shipped_pipelines())}; `htdata pipelines list` shows them)")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from e
    return PipelineConfig.from_dict(data, where=str(path))


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
