"""Stage timers (wall seconds per named stage) and the process's peak memory, for the reports of the edit job, the
proxy build and the demo."""

from __future__ import annotations

import resource
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager


class Stopwatch:
    """Wall seconds per named stage in ``seconds`` (a stage that runs again adds to its total).

    ``seconds``: the dict to fill (default a new one); ``digits``: each total rounded to this many decimals (None:
    not rounded); ``on_stage(name)`` is called as each stage starts (a progress display).
    """

    def __init__(
        self,
        on_stage: Callable[[str], None] | None = None,
        *,
        seconds: dict[str, float] | None = None,
        digits: int | None = 4,
    ) -> None:
        self.seconds: dict[str, float] = {} if seconds is None else seconds
        self.on_stage = on_stage
        self.digits = digits

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name`` (not recorded when the block raises)."""
        if self.on_stage:
            self.on_stage(name)
        start = time.perf_counter()
        yield
        total = self.seconds.get(name, 0.0) + time.perf_counter() - start
        self.seconds[name] = total if self.digits is None else round(total, self.digits)


def peak_rss_mb() -> float:
    """The process's peak resident memory so far in MiB (``getrusage``: kilobytes on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(peak / (1 << 20 if sys.platform == "darwin" else 1 << 10), 1)
