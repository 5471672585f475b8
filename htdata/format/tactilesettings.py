"""A pipeline's `[tactile]` section: how the tactile members are written (EXR compression, maps stored
or rendered from raw rows: htdata/format/mapstorage.py), apart from the rest of the pipeline.

An ingest pipeline (htdata/ingest/pipeline.py) holds one as its `tactile`. Keys are checked by
schemas/pipeline.schema.json (`[tactile]`) and `validate` (the rule between maps, keep_raw and raster_mode).

    [tactile]
    compression = "zip"       # EXR compression of the maps (htdata/format/tactilecodec.py)
    raster_mode = "nearest"   # taxels -> map (htdata/glove/rasterise.py)
    keep_bend = true          # bend_<hand>.npy where the layout has bend cells
    keep_raw = true           # raw_<hand>.npy: every glove row as read (source dtype), full rate
    chunk_frames = 64         # tactile frames read / normalised / rasterised per step (memory bound)
    maps = "auto"             # "auto" | "stored" | "raw" (MapStorage)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from htdata.format.mapstorage import MapStorage


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
