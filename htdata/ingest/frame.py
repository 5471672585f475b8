"""One frame of an episode as the ingest hands it on (`Frame`), and the rule that names its errors.

Error policy: everything raised while a frame is being processed leaves the
episode's generator (htdata.ingest.episode) as an `EpisodeError` naming file,
episode and that frame (`frame_errors`); the caller decides what a failed
episode means (the ingest unit records it and goes on with the next episode).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from htdata.errors import EpisodeError
from htdata.ingest.fullrate import RawRows


@dataclass
class Frame:
    """What one kept frame's sample needs, decoded (see htdata.format.table for the sample dict)."""
    key: str                       # sample key (episode id + frame index)
    source_frame: int              # RGB frame index in the source
    meta: dict                     # the sample's JSON member
    rgb: np.ndarray | None         # (size,size,3) uint8 RGB; None when RGB was not asked for
    maps: dict[str, np.ndarray]    # hand -> (224,224) float32 in [0,1] (float16 if the stream was asked for it)
    bends: dict[str, np.ndarray] = field(default_factory=dict)   # hand -> (K,) float32
    # hand -> rows gathered while the frame waits (htdata.ingest.fullrate); arrays once `finish_raw` ran
    raw: dict = field(default_factory=dict)

    def finish_raw(self, grids: dict[str, tuple[int, int]]) -> "Frame":
        """Turn the gathered raw rows into (R,H,W) arrays in time order and name them in meta."""
        if self.raw and isinstance(next(iter(self.raw.values())), RawRows):
            arrays, t_ns, rows, paired = {}, {}, {}, {}
            for h, rr in self.raw.items():
                arrays[h], info = rr.finish(grids[h], None)
                t_ns[h], rows[h], paired[h] = info["t_ns"], info["row"], info["paired"]
            self.raw = arrays
            self.meta.update({"raw_t_ns": t_ns, "raw_row": rows, "raw_paired": paired})
        return self

    def sample(self) -> dict:
        return {"meta": self.meta, "rgb": self.rgb, "tactile": self.maps, "bend": self.bends, "raw": self.raw}


@contextmanager
def frame_errors(ref, frame: int | None):
    """Whatever is raised inside names this episode and `frame` (an EpisodeError keeps its own frame)."""
    try:
        yield
    except EpisodeError as exc:
        named = exc.at_frame(frame)
        if named is exc:
            raise
        raise named from exc
    except Exception as exc:
        raise EpisodeError(ref, frame, f"{type(exc).__name__}: {exc}") from exc
