"""An episode's RGB frames for the ingest: the video read once, the frames the pairing dropped kept.

`RgbFetcher` hands out frames by index while decoding the video once, in
file order; `RgbOnlyFrames` turns the RGB frames without tactile (dropped by
the pairing, htdata.source.sync) into RGB-only samples, in time order
between the paired frames (htdata/ingest/fullrate.py). `rgb_source` builds
both for one episode (none for a glove-only recording).
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from htdata.errors import EpisodeError
from htdata.format.shardio import sample_key
from htdata.format.table import HANDS
from htdata.ingest.frame import Frame, frame_errors
from htdata.ingest.pipeline import PipelineConfig
from htdata.ingest.tally import EpisodeTally
from htdata.ingest.timing import StageClock


class RgbFetcher:
    """Hand out RGB frames by index while reading the video once, in file order.

    Frames wanted later (only when timestamps were out of file order) wait as
    resized arrays; unwanted frames are skipped without resizing.
    """

    def __init__(self, ref, frames, wanted: np.ndarray, resize, clock: StageClock):
        self.ref = ref
        self.frames = iter(frames)
        self.wanted = set(int(i) for i in wanted)
        self.resize = resize
        self.clock = clock
        self.pending: dict[int, np.ndarray] = {}

    def get(self, index: int) -> np.ndarray:
        index = int(index)
        while index not in self.pending:
            try:
                with self.clock.stage("decode"):
                    i, frame = next(self.frames)
            except StopIteration:
                raise EpisodeError(self.ref, index, "RGB stream ended before this frame") from None
            i = int(i)
            if i in self.wanted:
                with self.clock.stage("resize"):
                    self.pending[i] = self.resize(frame, i)
        self.wanted.discard(index)
        return self.pending.pop(index)

    def discard(self, index: int) -> None:
        self.wanted.discard(int(index))
        self.pending.pop(int(index), None)


def rgb_source(ref, cfg: PipelineConfig, streams, sync, clock: StageClock, with_rgb: bool):
    """(RgbFetcher or None, unpaired RGB frames to keep): none of either for a glove-only recording."""
    if not (with_rgb and streams.has_video):
        return None, []
    rgb_cfg = cfg.rgb
    unpaired = _unpaired_rgb(streams, sync) if rgb_cfg.keep_unpaired else []

    def resize(frame, i):
        return rgb_cfg.square(frame, where=f"{ref.source_ref} [{ref.episode_id}] frame {i}")

    wanted = np.concatenate([sync.rgb_index, np.asarray([i for _, i, _ in unpaired], dtype=np.int64)])
    return RgbFetcher(ref, streams.iter_rgb(), wanted, resize, clock), unpaired


def _unpaired_rgb(streams, sync) -> list[tuple[int, int, str]]:
    """(t_rgb_ns, rgb index, reason) of the RGB frames the pairing dropped, in time order."""
    ts = np.asarray(streams.rgb_timestamps_ns, dtype=np.int64)
    # a frame stamped like another has no time of its own (sync kept the first): it stays dropped, counted
    return sorted((int(ts[i]), int(i), reason) for i, reason in sync.dropped if reason != "duplicate_timestamp")


class RgbOnlyFrames:
    """RGB frames without tactile, handed out in time order between the paired frames (htdata.ingest.fullrate)."""

    def __init__(self, ref, tally: EpisodeTally, fetcher, unpaired: list[tuple[int, int, str]]):
        self.ref, self.tally, self.fetcher = ref, tally, fetcher
        self.unpaired = unpaired
        self.next = 0

    def before(self, when: tuple[int, int] | None) -> Iterator["Frame"]:
        """Frames of the sync-dropped RGB frames before (t, index) `when` (all the rest when None)."""
        while self.next < len(self.unpaired) and (when is None or self.unpaired[self.next][:2] < when):
            t, i, reason = self.unpaired[self.next]
            self.next += 1
            yield self.frame(t, i, reason)

    def frame(self, t_rgb: int, i: int, reason: str) -> "Frame":
        ref, tally = self.ref, self.tally
        with frame_errors(ref, i):
            rgb = self.fetcher.get(i)
        key = sample_key(ref.episode_id, tally.frames)
        meta = {"key": key, "episode_id": ref.episode_id, "frame_index": tally.frames, "source_frame": i,
                "t_rgb_ns": t_rgb, "t_tactile_ns": {}, "sync_offset_ns": {},
                "hands": {h: False for h in HANDS}, "rgb_only": reason}
        tally.frames += 1
        tally.rgb_only[reason] = tally.rgb_only.get(reason, 0) + 1
        return Frame(key=key, source_frame=i, meta=meta, rgb=rgb, maps={}, bends={}, raw={})
