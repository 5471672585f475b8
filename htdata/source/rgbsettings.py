"""A pipeline's `[rgb]` section: how an RGB frame becomes the stored 224x224 JPEG (htdata/source/rgb.py
crops and resizes it; the JPEG quality goes to the format's encoder), apart from the rest of the pipeline.

An ingest pipeline (htdata/ingest/pipeline.py) holds one as its `rgb`. Keys are checked by
schemas/pipeline.schema.json (`[rgb]`) and by `to_square_224` when a frame is resized.

    [rgb]
    size = 224                # format_version 1 stores 224x224 frames (the schema allows only 224)
    quality = 95              # JPEG quality
    crop = "center"           # htdata.source.rgb.CROPS
    interpolation = "area"    # htdata.source.rgb.INTERPOLATIONS
    keep_unpaired = true      # RGB frames without tactile within the skew become RGB-only samples
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from htdata.source.rgb import to_square_224


@dataclass
class RgbConfig:
    size: int = 224
    quality: int = 95
    crop: str = "center"
    interpolation: str = "area"
    keep_unpaired: bool = True   # RGB frames without tactile within the skew become RGB-only samples

    @classmethod
    def from_dict(cls, data: dict) -> "RgbConfig":
        """[rgb] as written (TOML / to_dict)."""
        return cls(**data)

    def to_dict(self) -> dict:
        return asdict(self)

    def square(self, frame, where: str = "rgb frame") -> np.ndarray:
        """One source frame (HxWx3 uint8, RGB order) as this section stores it: (size,size,3) uint8."""
        return to_square_224(frame, self.size, self.crop, self.interpolation, where=where)
