"""Sample encoding off the main thread, results in frame order.

`encode_sample` is mostly EXR (htdata/format/exrzip.py: ISA-L deflate) and JPEG (cv2):
both release the GIL while they compress (the codec bench's "2 threads" column
measures it: ~2x the maps per second on 2 cores), so while the worker's main
thread reads, normalises and rasterises the next frames, `encode_threads()`
threads encode the previous ones (none where a worker has no spare core). The bytes are the same as inline: each
sample is encoded by the same call, and results are handed back in the
order the frames came. At most `DEPTH` samples wait (each ~0.5 MB of maps +
RGB), so memory stays bounded.

An episode without video (a glove-only recording) encodes inline: its
samples' only GIL-free work is the maps' deflate, ~14 calls of ~10 us per
map, and each one hands the GIL back and forth with the main thread, so 2
threads cost more CPU than they take off it (the bench's glove-only
recording, 1 worker, $HTDATA_ENCODE_THREADS 2 vs 0: ~25% more CPU, ~10%
fewer frames/s). The pool starts its threads at the first sample that has
an RGB frame.

A failure is raised by `put` / `drain` for the frame it belongs to, naming
it (frame_errors), as the inline encode did.
"""

from __future__ import annotations

import os
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

from htdata.format.table import CodecSettings, encode_sample
from htdata.ingest.frame import frame_errors

# $HTDATA_ENCODE_THREADS: 0 encodes inline on the calling thread. A pool worker gets it from its share of
# the cores (executors.limit_threads): threads only pay where a core is spare; with as many workers as
# cores they cost ~6% (ingest of the medium OpenTouch corpus, 2 workers on 2 cores, inline vs 2 threads).
THREADS_ENV = "HTDATA_ENCODE_THREADS"
DEFAULT_THREADS = 2
DEPTH = 8


def encode_threads() -> int:
    """Encode threads for this process: $HTDATA_ENCODE_THREADS, else DEFAULT_THREADS."""
    return max(0, int(os.environ.get(THREADS_ENV, DEFAULT_THREADS)))


class EncodePool:
    """`with EncodePool(settings, ref) as pool:` then `pool.put(...)` per frame and `pool.drain()` at the end."""

    def __init__(self, settings: CodecSettings, ref, threads: int | None = None, depth: int = DEPTH):
        self.threads = encode_threads() if threads is None else threads
        self.settings, self.ref, self.depth = settings, ref, max(1, depth)
        self._pool: ThreadPoolExecutor | None = None     # started by the first sample with RGB (module docstring)
        self._pending: deque[tuple[str, int, Future]] = deque()

    def __enter__(self) -> "EncodePool":
        return self

    def __exit__(self, *exc) -> None:
        for _, _, fut in self._pending:
            fut.cancel()
        self._pending.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=True)

    def put(self, key: str, sample: dict, source_frame: int) -> list[tuple[str, dict[str, bytes]]]:
        """Queue one frame's sample; return the (key, members) done, oldest first, once the queue is full."""
        if self._pool is None and self.threads > 0 and sample.get("rgb") is not None:
            self._pool = ThreadPoolExecutor(max_workers=self.threads, thread_name_prefix="htdata-encode")
        if self._pool is None:
            with frame_errors(self.ref, source_frame):
                return [(key, encode_sample(sample, self.settings, key))]
        self._pending.append((key, source_frame, self._pool.submit(encode_sample, sample, self.settings, key)))
        done = []
        while len(self._pending) > self.depth:
            done.append(self._next())
        return done

    def drain(self) -> list[tuple[str, dict[str, bytes]]]:
        return [self._next() for _ in range(len(self._pending))]

    def _next(self) -> tuple[str, dict[str, bytes]]:
        key, source_frame, fut = self._pending.popleft()
        with frame_errors(self.ref, source_frame):
            return key, fut.result()
