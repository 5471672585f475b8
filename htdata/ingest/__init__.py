"""Ingest: raw recordings -> a committed, sharded dataset (the `htdata ingest` command is
htdata/commands/ingest.py).

    pipeline.py ingest pipelines as data: pipelines/*.toml -> PipelineConfig (checked, with --set overrides)
    plan.py     sources, discovery, layouts resolved once per run, one work unit per episode, who hashes what
    gloverest.py  a raw-count glove's rest pooled over the run's recordings of it (the default with >= 3)
    append.py   against the current version: reuse / relabel / re-ingest / keep; the parent's parts
                (reused units are re-packed by htdata/write/repack.py, shared with curate)
    chunk.py    one chunk of glove rows: read, check, normalise, out-of-range policy, raw rows per frame
    episode.py  `EpisodeStream`: one episode as a stream of canonical frames, then its tally (shared with the benchmarks)
    frame.py    `Frame` (one kept frame, decoded) and `frame_errors` (errors name the episode and frame)
    rgbframes.py  an episode's RGB frames: the video read once in file order, RGB-only frames kept
    fullrate.py every recorded frame kept: which sample stores which raw glove row, RGB frames without tactile
    tally.py    what one episode's ingest learned (`EpisodeTally`), for its record in episodes.jsonl
    unit.py     one work unit: encode (format.encode_sample) + spool + shards + done record; error policy
    encodepool.py  samples encoded in threads (the EXR binding and cv2 release the GIL), frame order kept
    workdir.py  the output directory while ingesting: unit records, leftovers, resume
    commit.py   compatibility with the parent; parent parts + unit records -> a new version
    run.py      `ingest()`: lock -> plan -> executor (executors.py) -> report -> commit
    timing.py   per-stage wall time (report["timing"])
    sourcesums.py  source files' sha256 (taken by the units that read them) checked against SHA256SUMS
                lists beside the recordings; --verify-sources
    recordingscan.py  raw recordings read for cell activity (`htdata layouts check --against` / `suggest`)

May import: the writers' shared layer (htdata.write), reading, the store, sources, the glove
model, the format and the base modules. Never curate (its sibling), validate, the benchmarks
or the commands.

Python use:

    from htdata.ingest import Source, ingest
    from htdata.ingest.pipeline import load_pipeline
    report = ingest([Source(load_pipeline("opentouch"), Path("/raw/ot"))], Path("OUT"), workers=2)
"""

from htdata.ingest.plan import Source, UnitTask, parse_sources
from htdata.ingest.run import EpisodeProgress, ingest

__all__ = ["EpisodeProgress", "Source", "UnitTask", "ingest", "parse_sources"]
