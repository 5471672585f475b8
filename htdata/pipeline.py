"""Ingest pipelines as data: `pipelines/*.toml` -> PipelineConfig.

A pipeline says how one source format becomes canonical samples: which
adapter reads it (and its params), which glove layout each hand uses, how
glove units are normalised (per layout), the sync tolerance, RGB and tactile
encoding, and the shard size. Files are checked twice: against
`schemas/pipeline.schema.json` (unknown keys are errors, named with the file)
and by `validate()` (cross-field rules the schema cannot express).

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

import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from htdata.normalise import NormaliseConfig
from htdata.resources import PIPELINES_DIR, validate_json



@dataclass
class AdapterConfig:
    name: str
    params: dict = field(default_factory=dict)


@dataclass
class SyncConfig:
    max_skew_ms: float = 20.0
    policy: str = "nearest"

    @property
    def max_skew_ns(self) -> int:
        return int(round(self.max_skew_ms * 1e6))


@dataclass
class RgbConfig:
    size: int = 224
    quality: int = 95
    crop: str = "center"
    interpolation: str = "area"


@dataclass
class TactileConfig:
    compression: str = "zip"
    raster_mode: str = "nearest"
    keep_bend: bool = True
    chunk_frames: int = 64   # tactile frames read/normalised/rasterised per step (memory bound)


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
    sync: SyncConfig = field(default_factory=SyncConfig)
    rgb: RgbConfig = field(default_factory=RgbConfig)
    tactile: TactileConfig = field(default_factory=TactileConfig)
    shards: ShardsConfig = field(default_factory=ShardsConfig)
    description: str = ""
    path: str = ""   # where it was loaded from (not part of the config's identity)

    def validate(self) -> "PipelineConfig":
        where = self.path or f"pipeline {self.name!r}"
        validate_json(self.to_dict(), "pipeline", where)
        for layout_id, cfg in self.normalise.items():
            cfg.validate(f"{where}: normalise.{layout_id}")
        return self

    def normalise_for(self, layout) -> NormaliseConfig:
        """The pipeline's config for this layout, else the layout's own value block."""
        if layout.layout_id in self.normalise:
            return self.normalise[layout.layout_id]
        return NormaliseConfig.from_layout_value(layout.value)

    def to_dict(self) -> dict:
        """Plain dict (the TOML content with defaults filled in); recorded in the manifest."""
        d = {
            "name": self.name,
            "adapter": {"name": self.adapter.name, "params": dict(self.adapter.params)},
            "layouts": dict(self.layouts),
            "normalise": {k: v.to_dict() for k, v in self.normalise.items()},
            "sync": asdict(self.sync),
            "rgb": asdict(self.rgb),
            "tactile": asdict(self.tactile),
            "shards": asdict(self.shards),
        }
        if self.description:
            d["description"] = self.description
        return d

    @classmethod
    def from_dict(cls, data: dict, where: str = "pipeline") -> "PipelineConfig":
        validate_json(data, "pipeline", where)
        cfg = cls(
            name=data["name"],
            adapter=AdapterConfig(name=data["adapter"]["name"], params=dict(data["adapter"].get("params", {}))),
            layouts=dict(data.get("layouts", {})),
            normalise={k: NormaliseConfig(**v) for k, v in data.get("normalise", {}).items()},
            sync=SyncConfig(**data.get("sync", {})),
            rgb=RgbConfig(**data.get("rgb", {})),
            tactile=TactileConfig(**data.get("tactile", {})),
            shards=ShardsConfig(**data.get("shards", {})),
            description=data.get("description", ""),
            path=where,
        )
        # TOML integers for float fields are fine; normalise them so to_dict() is stable.
        for n in cfg.normalise.values():
            n.max_value = float(n.max_value)
            n.scale = float(n.scale)
        cfg.sync.max_skew_ms = float(cfg.sync.max_skew_ms)
        return cfg.validate()


def resolve_pipeline_path(name_or_path: str | Path) -> Path:
    """A path to a .toml, or a bare name looked up in the project's pipelines/ folder."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    return PIPELINES_DIR / f"{name_or_path}.toml"


def load_pipeline(name_or_path: str | Path) -> PipelineConfig:
    """Load and validate a pipeline TOML; errors name the file."""
    path = resolve_pipeline_path(name_or_path)
    if not path.is_file():
        raise FileNotFoundError(f"pipeline file not found: {path}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: invalid TOML: {e}") from e
    return PipelineConfig.from_dict(data, where=str(path))
