"""A pipeline's `[sync]` section: how far apart paired frames may be (htdata/source/sync.py) and the
clock lag between the streams (htdata/source/lag.py), apart from the rest of the pipeline.

An ingest pipeline (htdata/ingest/pipeline.py) holds one as its `sync` and hands it to the
pairing and the lag estimate, which need nothing else of a pipeline. Keys and their checks live here
and in schemas/pipeline.schema.json (`[sync]`), so a new key is one edit beside the code that reads it.

    [sync]
    max_skew_ms = 20          # an RGB frame without tactile this close is dropped (reason listed)
    policy = "nearest"        # htdata.source.sync.SYNC_POLICIES
    lag = "none"              # "none" | "estimate" | a number of ms (tactile - RGB clock)
    max_lag_ms = 500          # the estimate searches within +-max_lag_ms
    min_confidence = 0.5      # an estimate is applied from this confidence on
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from htdata.errors import ConfigError

LAG_MODES = ("none", "estimate")
MAX_SYNC_MS = 3_600_000   # sync tolerances past an hour are typos (1e300 overflowed int64 nanoseconds)
_LAG_KEYS = ("lag", "max_lag_ms", "min_confidence")


@dataclass
class SyncConfig:
    """Args:
        max_skew_ms: largest |t_rgb - t_tactile| a pair may have.
        policy: how an RGB frame finds its tactile frame (htdata.source.sync.SYNC_POLICIES).
        lag: "none" (clocks as recorded), "estimate" (per episode from the content, applied when confidence
            >= min_confidence, searched within +-max_lag_ms), or a number of ms (tactile - RGB clock,
            subtracted from every tactile timestamp).
        max_lag_ms: the estimate's search range.
        min_confidence: the confidence from which an estimate is applied.
    """
    max_skew_ms: float = 20.0
    policy: str = "nearest"
    lag: str | float = "none"
    max_lag_ms: float = 500.0
    min_confidence: float = 0.5

    @property
    def max_skew_ns(self) -> int:
        return int(round(self.max_skew_ms * 1e6))

    @property
    def max_lag_ns(self) -> int:
        return int(round(self.max_lag_ms * 1e6))

    @classmethod
    def from_dict(cls, data: dict) -> "SyncConfig":
        """[sync] as written (TOML / to_dict); TOML integers for float keys become floats, so to_dict() is stable."""
        cfg = cls(**data)
        cfg.max_skew_ms = float(cfg.max_skew_ms)
        for key in ("max_lag_ms", "min_confidence") + (() if isinstance(cfg.lag, str) else ("lag",)):
            if isinstance(getattr(cfg, key), int) and not isinstance(getattr(cfg, key), bool):
                setattr(cfg, key, float(getattr(cfg, key)))
        return cfg

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
        for key in _LAG_KEYS:
            if getattr(self, key) != getattr(defaults, key):
                d[key] = getattr(self, key)
        return d
