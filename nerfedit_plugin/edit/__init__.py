"""Editing: edit specs, the Deformer contract, the tet proxy, the lift into it, and the edit job."""

from typing import Any

_JOB = ("run_edit", "EditResult", "default_cache_dir", "Stopwatch")


def __getattr__(name: str) -> Any:  # the 0.1.0 module ``nerfedit_plugin.edit`` was today's ``edit.job``
    if name in _JOB:
        from nerfedit_plugin.edit import job

        return getattr(job, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
