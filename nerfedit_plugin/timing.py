"""Stage timers (wall seconds per named stage) and the process's peak memory, for the reports of the edit job, the
proxy build and the demo; and the progress hook of long stages (what a progress display listens to)."""

from __future__ import annotations

import resource
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Protocol


class Progress(Protocol):
    """What long work calls to report how far it is: ``progress(done, total=None, detail="")``.

    ``total`` None: uncountable work (a factorisation, pytetwild), ``detail`` says what runs. Otherwise ``done`` of
    ``total`` work units are done: within one bar (one ``total``, one kind of ``detail``) ``done`` never decreases,
    and the bar ends with ``done == total`` (work that ends early, an ARAP solve that converges, jumps to the end).
    A report with another ``total`` starts a new bar. Must return quickly (it may be called once per iteration)."""

    def __call__(self, done: int, total: int | None = None, detail: str = "") -> None: ...


def no_progress(done: int, total: int | None = None, detail: str = "") -> None:
    """The :class:`Progress` nobody listens to."""


def labelled(progress: Progress, label: str) -> Progress:
    """``progress`` with ``label`` leading every detail (one part of a stage that runs several)."""

    def report(done: int, total: int | None = None, detail: str = "") -> None:
        progress(done, total, f"{label}: {detail}" if detail else label)

    return report


class Span:
    """Units ``start … start + size`` of a bar of ``total`` units of ``progress`` (one frame of a sequence, one pass of
    several): positions in it are reported with ``label`` leading the detail."""

    def __init__(self, progress: Progress, start: int, size: int, total: int, label: str = "") -> None:
        self.progress, self.start, self.size, self.total, self.label = progress, start, size, total, label
        self.done = 0
        """The last position reported, in units from ``start``."""

    def at(self, done: int | None = None, detail: str = "") -> None:
        """Report ``done`` units into the span (at most ``size``; None: where it was), with ``detail``."""
        self.done = self.done if done is None else min(done, self.size)
        self.progress(self.start + self.done, self.total, " · ".join(text for text in (self.label, detail) if text))

    def end(self, detail: str = "") -> None:
        """Report the span done (work that stops early jumps to its end)."""
        self.at(self.size, detail)

    def iterations(self) -> Callable[[int, float], None]:
        """A minimiser's ``callback(k, energy)`` (e.g. :meth:`~nerfedit_plugin.geometry.arap.ArapSolver.solve`'s):
        iteration ``k`` at unit ``k``, detail the iteration and its relative energy decrease."""
        previous: float | None = None

        def callback(k: int, energy: float) -> None:
            nonlocal previous
            decrease = f" · ΔE/E {(previous - energy) / abs(previous):.1e}" if previous else ""
            previous = energy
            self.at(k, f"iteration {k}{decrease}")

        return callback


ProgressListener = Callable[[str, int, int | None, str], None]
"""``on_progress(stage, done, total, detail)``: a :class:`Progress` report of the stage ``stage``."""


class Stopwatch:
    """Wall seconds per named stage in ``seconds`` (a stage that runs again adds to its total).

    ``seconds``: the dict to fill (default a new one); ``digits``: each total rounded to this many decimals (None:
    not rounded); ``on_stage(name)`` is called as each stage starts and ``on_progress(stage, done, total, detail)``
    for each :meth:`progress` report inside one (a progress display).
    """

    def __init__(
        self,
        on_stage: Callable[[str], None] | None = None,
        *,
        on_progress: ProgressListener | None = None,
        seconds: dict[str, float] | None = None,
        digits: int | None = 4,
    ) -> None:
        self.seconds: dict[str, float] = {} if seconds is None else seconds
        self.on_stage = on_stage
        self.on_progress = on_progress
        self.digits = digits
        self.current: str | None = None
        """The stage running (None outside every stage)."""

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name`` (not recorded when the block raises)."""
        if self.on_stage:
            self.on_stage(name)
        outer, self.current = self.current, name
        start = time.perf_counter()
        try:
            yield
        finally:
            self.current = outer
        total = self.seconds.get(name, 0.0) + time.perf_counter() - start
        self.seconds[name] = total if self.digits is None else round(total, self.digits)

    def progress(self, done: int, total: int | None = None, detail: str = "") -> None:
        """The :class:`Progress` of the current stage: passed to ``on_progress`` (dropped outside a stage or without
        a listener)."""
        if self.on_progress is not None and self.current is not None:
            self.on_progress(self.current, done, total, detail)


def peak_rss_mb() -> float:
    """The process's peak resident memory so far in MiB (``getrusage``: kilobytes on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(peak / (1 << 20 if sys.platform == "darwin" else 1 << 10), 1)
