"""Timing helpers: medians of repeats, and ratios measured in the same run."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

__all__ = ["median_time"]


def median_time(fn: Callable[[], object], *, repeats: int = 5, min_seconds: float = 0.05, warmup: int = 3) -> float:
    """Return the median over ``repeats`` of the mean time of one call of ``fn`` [s].

    Each repeat runs ``fn`` enough times to last about ``min_seconds`` (calibrated once).

    Example:
        >>> median_time(lambda: sum(range(100)), repeats=3, min_seconds=0.001) > 0
        True
    """
    for _ in range(warmup):
        fn()
    start = time.perf_counter()
    fn()
    single = max(time.perf_counter() - start, 1e-7)
    calls = max(1, int(min_seconds / single))
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        samples.append((time.perf_counter() - start) / calls)
    return statistics.median(samples)
