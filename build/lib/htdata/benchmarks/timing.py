"""Small timing helpers shared by the benchmarks."""

from __future__ import annotations

import time
from typing import Callable


def best_ms(fn: Callable[[], object], repeat: int = 5, number: int = 1) -> float:
    """Best-of-`repeat` wall time of `number` calls, in ms per call (best = least noise)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best * 1e3
