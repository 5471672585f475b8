"""Ingest: raw recordings -> a committed, sharded dataset (the `htdata ingest` command is
htdata/commands/ingest.py).

    plan.py     sources, discovery, layouts resolved once per episode, work units
    episode.py  `episode_frames`: one episode as a stream of canonical frames (shared with the benchmarks)
    unit.py     one work unit: encode (format.encode_sample) + spool + shards + done record; error policy
    workdir.py  the output directory while ingesting: ownership, unit records, leftovers, resume
    commit.py   unit records -> layouts/, episodes.jsonl, index.npy, dataset.json (last)
    run.py      `ingest()`: plan -> executor (executors.py) -> report -> commit
    timing.py   per-stage wall time (report["timing"])

Python use:

    from htdata.ingest import Source, ingest
    from htdata.pipeline import load_pipeline
    report = ingest([Source(load_pipeline("opentouch"), Path("/raw/ot"))], Path("OUT"), workers=2)
"""

from htdata.ingest.plan import Source, UnitTask, pack_units, parse_sources, unit_target_frames
from htdata.ingest.run import EpisodeProgress, ingest

__all__ = ["EpisodeProgress", "Source", "UnitTask", "ingest", "pack_units", "parse_sources", "unit_target_frames"]
