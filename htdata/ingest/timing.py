"""Stage timing of an ingest: wall seconds per stage, summed per unit, summarised in report["timing"]."""

from __future__ import annotations

import time
from contextlib import contextmanager

STAGES = ("hash", "decode", "resize", "normalise", "rasterise", "encode", "write")


class StageClock:
    """Wall seconds per ingest stage, summed over a unit (perf_counter around whole calls).

    hash = the sha256 of the source files the unit was given (htdata/ingest/sourcesums.py);
    decode = opening the episode's streams + RGB decode + tactile reads;
    resize = rgb.to_square_224; normalise; rasterise (incl. bend vectors and
    contact stats); encode = format.encode_sample (EXR + JPEG + bend .npy +
    sample JSON); write = spool writes + replay into the shard writer +
    closing shards.
    """

    def __init__(self):
        self.seconds = dict.fromkeys(STAGES, 0.0)

    @contextmanager
    def stage(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - t0

    def as_record(self) -> dict:
        return {f"{k}_s": v for k, v in self.seconds.items()}


def timing_summary(records: list[dict], total_s: float) -> dict:
    """report["timing"] from the records of the units run in this invocation."""
    worker_s = sum(float(r.get("seconds", 0.0)) for r in records)
    out = {"frames": sum(int(r["frames"]) for r in records), "total_s": total_s, "worker_s": worker_s,
           # the units' processes' CPU (their encode threads included): the cores a quiet machine would spend
           "worker_cpu_s": sum(float(r.get("cpu_s", 0.0)) for r in records)}
    staged = 0.0
    for name in STAGES:
        v = sum(float(r.get("timing", {}).get(f"{name}_s", 0.0)) for r in records)
        out[f"{name}_s"] = v
        staged += v
    out["other_s"] = max(worker_s - staged, 0.0)
    return out
