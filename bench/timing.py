"""The benchmarks' one timer: the median wall time of a call, after warm-up calls."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def warm_median_s(call: Callable[[], object], repeats: int, warmup: int = 1) -> float:
    """Median wall time (s, ``time.perf_counter``) of ``repeats`` calls of ``call``, after
    ``warmup`` calls that are not timed (compilation, caches)."""
    for _ in range(warmup):
        call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return statistics.median(times)
