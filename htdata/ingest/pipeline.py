"""Ingest pipelines as data: `pipelines/*.toml` -> PipelineConfig.

A pipeline says how one source format becomes canonical samples: which
adapter reads it (and its params), which glove layout each hand uses, how
glove units are normalised (per layout), the sync tolerance and clock lag
(`[sync] lag`: htdata/source/lag.py), RGB and tactile encoding, and the shard
size. Files are checked three times: against
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

Long because every section's dataclass lives beside the loader that checks them
against schemas/pipeline.schema.json, so a new key is one edit in one file.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from htdata.errors import ConfigError
from htdata.format.mapstorage import MapStorage
from htdata.format.table import CodecSettings
from htdata.glove.codecrule import CodecChoice
from htdata.glove.layouts import nearest_hint
from htdata.glove.normalise import NormaliseConfig
from htdata.glove.normalisesettings import NormaliseSettings
from htdata.resources import PIPELINES_DIR, validate_json
from htdata.settings import apply_settings, parse_setting  # noqa: F401  (parse_setting: an old name of this module)
from htdata.source.adapters import ADAPTERS
from htdata.source.adapters.params import check_declared_params
from htdata.source.lag import LAG_MODES


@dataclass
class AdapterConfig:
    name: str
    params: dict = field(default_factory=dict)


MAX_SYNC_MS = 3_600_000   # sync tolerances past an hour are typos (1e300 overflowed int64 nanoseconds)


@dataclass
class SyncConfig:
    max_skew_ms: float = 20.0
    policy: str = "nearest"
    # Tactile-video lag (htdata/source/lag.py): "none" (clocks as recorded), "estimate" (per episode from the
    # content, applied when confidence >= min_confidence, searched within +-max_lag_ms), or a number of
    # ms (tactile - RGB clock, subtracted from every tactile timestamp).
    lag: str | float = "none"
    max_lag_ms: float = 500.0
    min_confidence: float = 0.5

    @property
    def max_skew_ns(self) -> int:
        return int(round(self.max_skew_ms * 1e6))

    def validate(self, where: str) -> "SyncConfig":
        if isinstance(self.max_skew_ms, bool) or not (isinstance(self.max_skew_ms, (int, float))
                                                      and 0 <= self.max_skew_ms <= MAX_SYNC_MS):
            raise ConfigError(f"{where}: sync.max_skew_ms must be in [0, {MAX_SYNC_MS}] (one hour), "
                              f"got {self.max_skew_ms!r}")
        if isinstance(self.lag, (int, float)) and not isinstance(self.lag, bool) and abs(self.lag) > MAX_SYNC_MS:
            raise ConfigError(f"{where}: sync.lag must be within +-{MAX_SYNC_MS} ms (one hour), got {self.lag!r}")
        if isinstance(self.lag, bool) or not (self.lag in LAG_MODES if isinstance(self.lag, str)
                                              else isinstance(self.lag, (int, float)) and math.isfinite(self.lag)):
            raise ConfigError(f"{where}: sync.lag must be one of {LAG_MODES} or a finite number of ms, got {self.lag!r}")
        if not (isinstance(self.max_lag_ms, (int, float)) and 0 < self.max_lag_ms <= 10_000):
            raise ConfigError(f"{where}: sync.max_lag_ms must be in (0, 10000], got {self.max_lag_ms!r}")
        if not (isinstance(self.min_confidence, (int, float)) and 0 <= self.min_confidence <= 1):
            raise ConfigError(f"{where}: sync.min_confidence must be in [0, 1], got {self.min_confidence!r}")
        return self

    def to_dict(self) -> dict:
        """Lag keys only when not default: a pipeline that never sets them keeps its to_dict() (and input
        fingerprints)."""
        d = {"max_skew_ms": self.max_skew_ms, "policy": self.policy}
        defaults = SyncConfig()
        for key in ("lag", "max_lag_ms", "min_confidence"):
            if getattr(self, key) != getattr(defaults, key):
                d[key] = getattr(self, key)
        return d


@dataclass
class RgbConfig:
    size: int = 224
    quality: int = 95
    crop: str = "center"
    interpolation: str = "area"
    keep_unpaired: bool = True   # RGB frames without tactile within the skew become RGB-only samples


@dataclass
class TactileConfig:
    compression: str = "zip"
    raster_mode: str = "nearest"
    keep_bend: bool = True
    keep_raw: bool = True    # raw_<hand>.npy: every glove row as read (source dtype), full rate
    chunk_frames: int = 64   # tactile frames read/normalised/rasterised per step (memory bound)
    # maps stored as EXR or rendered by the readers from the raw rows: htdata/format/mapstorage.py
    maps: MapStorage = MapStorage.AUTO

    @classmethod
    def from_dict(cls, data: dict, where: str) -> "TactileConfig":
        """[tactile] as written (TOML / to_dict): `maps` parsed into a MapStorage (absent: AUTO)."""
        maps = MapStorage.parse(data["maps"], where) if "maps" in data else MapStorage.AUTO
        return cls(**{**data, "maps": maps})

    def validate(self, where: str) -> "TactileConfig":
        self.maps.check_tactile(self.keep_raw, self.raster_mode, where)
        return self

    def to_dict(self) -> dict:
        d = asdict(self)
        del d["maps"]
        if self.maps.pipeline_value is not None:   # only "raw" is written (MapStorage.pipeline_value)
            d["maps"] = self.maps.pipeline_value
        return d


@dataclass
class CodecConfig:
    """[codec]: tactile = "auto" (default: the EXR pixel type the rule in htdata/glove/codecrule.py picks for the
    dataset's gloves) or an explicit "exr_half" / "exr_float"; the compression is [tactile] compression.

    `choice` is not written by hand: the ingest fills it in when it resolves the setting for a run
    (`PipelineConfig.with_codec_choice`), so workers and the manifest see one resolved codec.
    """
    tactile: str = "auto"
    choice: dict | None = None       # htdata.glove.codecrule.CodecChoice.info()

    def to_dict(self) -> dict:
        return {"tactile": self.tactile, **({"choice": dict(self.choice)} if self.choice else {})}


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
        """What normalising needs of this pipeline (htdata.glove.normalisesettings), e.g. for `htdata renormalise`."""
        return NormaliseSettings(name=self.name, path=self.path, normalise=self.normalise,
                                 normalise_given=self.normalise_given, layouts=self.layouts,
                                 shared_layouts=self.shared_layouts, settings=self.settings,
                                 fit_frames=self.tactile.chunk_frames)

    def check_layout_names(self, used_ids: set[str], used_hands: set[str] | None, scope: str,
                           why: str = "") -> None:
        """Refuse layout ids this pipeline names that no recording of `scope` uses (NormaliseSettings)."""
        self.normalise_settings().check_layout_names(used_ids, used_hands, scope, why)

    def codec_choice(self):
        """The resolved tactile codec (htdata.glove.codecrule.CodecChoice); the ingest resolves it first."""

        if self.codec.choice is None:
            raise ValueError(f"{self.path or self.name}: [codec] tactile = {self.codec.tactile!r} is not resolved "
                              f"for a dataset yet (htdata.glove.codecrule.resolve_sources / with_codec_choice)")
        return CodecChoice.from_info(self.codec.choice)

    def with_maps(self, maps: MapStorage) -> "PipelineConfig":
        """A copy whose [tactile] maps is `maps` (an ingest resolves AUTO before its units run)."""
        import copy

        cfg = copy.deepcopy(self)
        cfg.tactile.maps = maps
        cfg.tactile.validate(self.path or self.name)
        return cfg

    def with_codec_choice(self, choice) -> "PipelineConfig":
        """A copy whose [codec] carries `choice` (a CodecChoice for this pipeline's compression)."""
        import copy

        if choice.compression != self.tactile.compression:
            raise ValueError(f"{self.path or self.name}: codec choice {choice.codec} does not match "
                              f"[tactile] compression {self.tactile.compression!r}")
        cfg = copy.deepcopy(self)
        cfg.codec.choice = choice.info()
        return cfg

    def codec_settings(self):
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
            "rgb": asdict(self.rgb),
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
            sync=SyncConfig(**data.get("sync", {})),
            rgb=RgbConfig(**data.get("rgb", {})),
            tactile=TactileConfig.from_dict(data.get("tactile", {}), where),
            codec=CodecConfig(**data.get("codec", {})),
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
            for name in ("rest_seconds", "baseline_percentile", "drift_window_s"):
                if isinstance(getattr(n, name), int) and not isinstance(getattr(n, name), bool):
                    setattr(n, name, float(getattr(n, name)))
        cfg.sync.max_skew_ms = float(cfg.sync.max_skew_ms)
        for key in ("max_lag_ms", "min_confidence") + (() if isinstance(cfg.sync.lag, str) else ("lag",)):
            if isinstance(getattr(cfg.sync, key), int) and not isinstance(getattr(cfg.sync, key), bool):
                setattr(cfg.sync, key, float(getattr(cfg.sync, key)))
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
