"""Timing helpers shared by the benchmarks (imported as ``timing``: a script's own folder is on ``sys.path``)."""

from __future__ import annotations

import time


def timed(fn) -> tuple[float, object]:
    """``(wall seconds, result)`` of one call ``fn()``."""
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


def best_of(fn, repeat: int, warmup: bool = False) -> float:
    """Smallest wall time (seconds) of ``repeat`` calls ``fn()``, after one untimed call if ``warmup``."""
    if warmup:
        fn()
    return min(timed(fn)[0] for _ in range(repeat))
