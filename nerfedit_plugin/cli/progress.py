"""StageProgress: the progress display of long CLI jobs (``nerfedit edit``, ``nerfedit demo``)."""

from __future__ import annotations

from rich.console import Console, RenderableType
from rich.progress import (
    BarColumn,
    Progress,
    ProgressBar,
    ProgressColumn,
    SpinnerColumn,
    Task,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text


class StageProgress:
    """A job's progress display (a context manager), fed by :class:`~nerfedit_plugin.timing.Stopwatch`'s
    ``on_stage`` and ``on_progress``: one line per stage with a spinner (✓ once done), a bar with done/total while
    the stage's work is countable, its elapsed time and what it is doing. Transient (gone when the job ends, before
    its report), and silent when ``console`` is not a terminal. ``prefix`` leads every stage name."""

    def __init__(self, console: Console, prefix: str = "") -> None:
        self.prefix, self.task = prefix, None
        self.display = Progress(
            _Spinner(finished_text="[green]✓"),
            TextColumn("[bold]{task.description}"),
            _Bar(bar_width=30),
            _Count(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[detail]}"),
            console=console,
            transient=True,
        )

    def __enter__(self) -> StageProgress:
        self.display.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop()
        self.display.stop()

    def on_stage(self, name: str) -> None:
        """A stage starts: the previous one is done."""
        self._stop()
        self.task = self.display.add_task(self.prefix + name, total=None, done=0, of=None, detail="")

    def on_progress(self, stage: str, done: int, total: int | None, detail: str) -> None:
        """A :class:`~nerfedit_plugin.timing.Progress` report of the current stage."""
        if self.task is not None:
            self.display.update(self.task, done=done, of=total, detail=detail)

    def _stop(self) -> None:
        if self.task is not None:
            self.display.stop_task(self.task)


class _Spinner(SpinnerColumn):
    """A spinner until the stage stops, then ``finished_text``."""

    def render(self, task: Task) -> RenderableType:
        return self.finished_text if task.stop_time is not None else self.spinner.render(task.get_time())


class _Bar(BarColumn):
    """The bar of the stage's countable work (task fields ``done`` of ``of``); blank while ``of`` is None."""

    def render(self, task: Task) -> RenderableType:
        if task.fields.get("of") is None:
            return Text()
        return ProgressBar(
            total=max(task.fields["of"], 1),
            completed=task.fields["done"],
            width=self.bar_width,
            animation_time=task.get_time(),
            style=self.style,
            complete_style=self.complete_style,
            finished_style=self.finished_style,
            pulse_style=self.pulse_style,
        )


class _Count(ProgressColumn):
    """``done/of`` of the stage's countable work; blank while ``of`` is None."""

    def render(self, task: Task) -> RenderableType:
        of = task.fields.get("of")
        return Text("" if of is None else f"{task.fields['done']}/{of}", style="progress.download")
