"""One work unit (in a worker process, a Ray task or inline): its episodes -> shards + a done record.

For each episode, `EpisodeStream` yields the kept frames; each is encoded
with `htdata.format.table.encode_sample` (codec settings from the pipeline; in
threads, results in frame order: htdata/ingest/encodepool.py) and spooled to
a temp file. Only a fully successful episode is replayed into
the unit's shards, so a bad episode never leaves half its frames behind.

Error policy (webdataset's `handler=` idea): `run_unit` hands any exception
an episode raises to `on_episode_error`, which turns it into a report
failure naming file, episode and frame; the unit goes on with its next
episode. A failure never crosses an episode boundary. A machine failure (a full
disk, an I/O error: `is_transient`) is marked "retry": the next run runs the
unit again instead of reusing its record.

The done record also carries the document of every layout the unit's
episodes used (`layout_entry`): the commit writes them into the dataset,
with each coverage map made from its document, so a layout file edited
during the run cannot slip in. It carries the unit's index rows as one
array (`part_from_unit` runs here, not in the driver) and the sha256 of the
source files the plan gave it to hash (`task.hash_files`, hashed on the
node that reads them, just before its episodes are decoded: the driver
reads no source byte; htdata/ingest/sourcesums.py checks them).

Test hooks (fault injection, used by tests/ingest/test_ingest.py):
HTDATA_TEST_FAULT_UNIT=U and HTDATA_TEST_FAULT=crash|hang make unit U
`os._exit(137)` or sleep forever right after its first episode reached the
shard writer (a temp shard exists, no unit record yet).
"""

from __future__ import annotations

import dataclasses
import errno
import os
import pickle
import time
from pathlib import Path

import numpy as np

from htdata.errors import EpisodeError
from htdata.fileio import write_bytes_atomic
from htdata.format.shardio import ShardWriter
from htdata.format.table import SHARDS_DIR, CodecSettings
from htdata.glove.calibration import episode_calibrations
from htdata.glove.layouts import Layout
from htdata.ingest.encodepool import EncodePool
from htdata.ingest.episode import EpisodeStream, EpisodeTally
from htdata.ingest.executors import parent_alive, report_progress
from htdata.ingest.pipeline import PipelineConfig
from htdata.ingest.timing import StageClock
from htdata.ingest.workdir import ROWS_DTYPE, clear_unit_files, dumps, encode_rows, spool_path, unit_record_path
from htdata.resources import validate_json
from htdata.source.adapters import get_adapter
from htdata.store.fsutil import sha256_file
from htdata.store.manifest import UnitResult
from htdata.store.parts import part_from_unit


class Spool:
    """Encoded samples of the current episode on disk (flat memory), replayed on success."""

    def __init__(self, path: Path):
        self.path = path
        self.f = None
        self.count = 0

    def start(self) -> None:
        self.close()
        self.f = open(self.path, "w+b")
        self.count = 0

    def add(self, key: str, members: dict[str, bytes]) -> None:
        pickle.dump((key, members), self.f, protocol=pickle.HIGHEST_PROTOCOL)
        self.count += 1

    def replay(self):
        self.f.flush()
        self.f.seek(0)
        for _ in range(self.count):
            yield pickle.load(self.f)

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None
        self.path.unlink(missing_ok=True)


def codec_settings(cfg: PipelineConfig) -> CodecSettings:
    return cfg.codec_settings()


def spool_episode(ref, cfg: PipelineConfig, adapter, spool: Spool, clock: StageClock) -> EpisodeTally:
    """Encode and spool every kept frame of one episode; raise on any failure."""
    settings = codec_settings(cfg)
    # maps not stored: none rendered here; readers render them from the raw rows. Half maps are rendered
    # as half (the bits the encoder would round float32 maps to), so the encoder converts nothing.
    stream = EpisodeStream(ref, cfg, adapter, clock, with_maps=cfg.tactile.maps.stores_maps,
                           map_dtype=np.float16 if settings.tactile_pixel_type == "half" else np.float32)
    spool.start()
    # encoded in threads while this one makes the next frames (encodepool.py); "encode" = the time
    # this thread waits for them, so the stages still add up to the wall time
    with EncodePool(settings, ref) as pool:
        for frame in stream:
            with clock.stage("encode"):
                done = pool.put(frame.key, frame.sample(), frame.source_frame)
            with clock.stage("write"):
                for key, members in done:
                    spool.add(key, members)
        with clock.stage("encode"):
            done = pool.drain()
        with clock.stage("write"):
            for key, members in done:
                spool.add(key, members)
    return stream.finished_tally()


# Failures of the machine, not of the recording: a full disk, a quota, an I/O error, no memory. A unit record
# holding one is not reused by the next run (workdir.load_valid_record): the episode is retried, not replayed.
TRANSIENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.ENOMEM, errno.EMFILE,
                              errno.ENFILE, errno.EROFS, errno.EAGAIN})


def is_transient(exc: BaseException | None) -> bool:
    """True when `exc`, or an exception it was raised from, is a machine failure (TRANSIENT_ERRNOS, MemoryError)."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, MemoryError) or (isinstance(exc, OSError) and exc.errno in TRANSIENT_ERRNOS):
            return True
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return False


def on_episode_error(ref, exc: BaseException) -> dict:
    """The error handler: a failed episode becomes one report failure (file, episode, frame, message);
    "retry": true marks a machine failure the next run retries (`is_transient`)."""
    if isinstance(exc, EpisodeError):
        file, frame, msg = exc.file, exc.frame, exc.message
    else:
        file, frame, msg = str(ref.source_ref).split("::", 1)[0], None, f"{type(exc).__name__}: {exc}"
    failure = {"stage": "ingest", "episode_id": ref.episode_id, "source": ref.source, "source_ref": ref.source_ref,
               "file": file, "frame": frame, "error": msg}
    if is_transient(exc):
        failure["retry"] = True
    return failure


def layout_entry(layout: Layout) -> dict:
    """What the commit needs of a layout: the document this unit used (its coverage is made from it)."""
    return {"document": layout.to_dict()}


def hash_sources(paths, clock: StageClock) -> tuple[dict[str, str], dict[str, str]]:
    """({path: sha256}, {path: why it could not be read}) of the files this unit was given to hash.

    One sequential read per file, right before the episode is decoded: the decoder then finds the
    bytes in this node's page cache, so storage (local or network) is read once. The check against
    the checksum lists is the driver's (htdata/ingest/sourcesums.py), so a failure here is reported,
    not raised: the file's episodes fail there.
    """
    digests, unreadable = {}, {}
    with clock.stage("hash"):
        for path in paths:
            try:
                digests[path] = sha256_file(path)
            except OSError as exc:
                unreadable[path] = f"{type(exc).__name__}: {exc.strerror or exc}"
    return digests, unreadable


def check_records(part, shard_names: list[str]) -> None:
    """Schema-check the unit's episode records here, in the worker (the commit trusts a unit's part,
    Part.records_checked); first_sample and shards, which the commit computes, get stand-ins."""
    for ep in part.episodes:
        validate_json({**ep, "first_sample": 0, "shards": shard_names}, "episode",
                      where=f"unit {part.unit}: episode {ep.get('episode_id')!r}")


def _fault_hook(unit: int) -> None:
    if os.environ.get("HTDATA_TEST_FAULT_UNIT") != str(unit):
        return
    mode = os.environ.get("HTDATA_TEST_FAULT", "crash")
    if mode == "hang":
        while True:
            time.sleep(3600)
    os._exit(137)


def run_unit(task) -> dict:
    """Ingest one unit (a plan.UnitTask); write its shards and its done record; return the (small) record."""
    out = Path(task.out)
    clear_unit_files(out, task.unit)  # idempotent: a retried unit starts clean
    cfg = PipelineConfig.from_dict(task.pipeline, where=task.pipeline_path or task.pipeline["name"])
    cfg = cfg.with_maps(task.maps)   # resolved by the driver, told explicitly (plan.UnitTask.maps)
    adapter = get_adapter(cfg.adapter.name)
    spool = Spool(spool_path(out, task.unit))
    episodes, failures, dropped, layouts, calibrations = [], [], [], {}, {}
    clock = StageClock()
    t0, cpu0 = time.perf_counter(), time.process_time()
    digests, unreadable = hash_sources(task.hash_files, clock)
    try:
        with ShardWriter(out / SHARDS_DIR, task.unit, cfg.shards.samples_per_shard) as writer:
            for ref in task.episodes:
                if not parent_alive():   # the ingest that asked for this unit is gone: stop, commit nothing
                    os._exit(1)
                try:
                    tally = spool_episode(ref, cfg, adapter, spool, clock)
                except Exception as exc:  # the error policy: a failure stays inside its episode
                    failures.append(on_episode_error(ref, exc))
                    report_progress({"unit": task.unit, "episode_id": ref.episode_id, "frames": 0})
                    continue
                with clock.stage("write"):
                    for key, members in spool.replay():
                        writer.add_sample(key, members)
                episodes.append(tally.record())
                dropped += [{"episode_id": ref.episode_id, "rgb_index": i, "reason": r}
                            for i, r in tally.dropped_sorted()]
                for layout in tally.layouts.values():
                    if layout.layout_id not in layouts:
                        layouts[layout.layout_id] = layout_entry(layout)
                calibrations.update(episode_calibrations(cfg.normalise_settings(), tally.layouts))
                report_progress({"unit": task.unit, "episode_id": ref.episode_id, "frames": tally.frames})
                _fault_hook(task.unit)
            with clock.stage("write"):
                shards = writer.close()
            # the index rows, made and checked here (a loop over samples): the driver only concatenates
            part = part_from_unit(UnitResult(unit=task.unit, shards=shards, samples=writer.samples,
                                             episodes=episodes))
            check_records(part, [s.name for s in shards])
    finally:
        spool.close()
    record = {
        "unit": task.unit, "fingerprint": task.fingerprint(),
        "episode_ids": [r.episode_id for r in task.episodes],
        "shards": [dataclasses.asdict(s) for s in shards],
        "rows": encode_rows(part.rows), "rows_dtype": ROWS_DTYPE, "frames": int(len(part.rows)),
        "episodes": part.episodes, "failures": failures, "dropped": dropped, "layouts": layouts,
        "calibrations": calibrations, "source_sha256": digests, "source_unreadable": unreadable,
        "seconds": time.perf_counter() - t0, "cpu_s": time.process_time() - cpu0, "timing": clock.as_record(),
    }
    write_bytes_atomic(unit_record_path(out, task.unit), dumps(record, compact=True))
    return record
