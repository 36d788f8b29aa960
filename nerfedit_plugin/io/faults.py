"""Named fault points: deterministic failures injected into the write paths, for tests that attack them.

The environment variable ``NERFEDIT_FAULT`` switches them on: a comma-separated list of ``NAME[@N][:ACTION]``.
At its ``N``-th call (default 1) ``fault_point(NAME)`` does ``ACTION``:

- ``raise`` (default) — raise :class:`InjectedFault` (an ``OSError``, like a full disk), so every ``with`` unwinds;
- ``term`` / ``int`` — send this process SIGTERM / SIGINT (handled as a real one: ``nerfedit`` exits 143 / 130);
- ``kill`` — SIGKILL this process: nothing runs any more, as with a crash or a power cut.

Without the variable a fault point costs one dictionary lookup. The points (:data:`POINTS`) sit where a failure
would do the most harm; tests check that afterwards every output is complete and valid, absent, or marked partial,
that the next write removes what was left staged, and that a previous good output is intact (docs/reliability.md).
"""

from __future__ import annotations

import os
import signal

VARIABLE = "NERFEDIT_FAULT"

POINTS = {
    "atomic.file.staged": "a file is written in its staging path, not yet renamed onto its target",
    "atomic.dir.staged": "an output folder is complete in its staging folder, not yet renamed onto its target",
    "atomic.dir.swap": "with --overwrite: the previous output is parked, the new one not yet in its place",
    "atomic.dir.committed": "the new output is in place, the parked previous one not yet deleted",
    "train.checkpoint": "train has written a checkpoint into its staging folder, marked partial",
    "render.frame": "render has written one frame's images into its staging folder",
}
"""Every fault point, and the moment it stands for."""

ACTIONS = ("raise", "term", "int", "kill")

_hits: dict[str, int] = {}


class InjectedFault(OSError):
    """The failure a fault point raises (action ``raise``)."""


def _armed(name: str) -> str | None:
    """The action armed at this call of the point ``name``, or None."""
    value = os.environ.get(VARIABLE)
    if not value:
        return None
    _hits[name] = hits = _hits.get(name, 0) + 1
    for entry in value.split(","):
        point, _, action = entry.strip().partition(":")
        point, _, nth = point.partition("@")
        if point not in POINTS or (action or "raise") not in ACTIONS or not (nth or "1").isdigit():
            raise ValueError(f"{VARIABLE}: {entry!r} is not NAME[@N][:ACTION] (names: {sorted(POINTS)}; {ACTIONS})")
        if point == name and hits == int(nth or 1):
            return action or "raise"
    return None


def fault_point(name: str) -> None:
    """Fail here when ``NERFEDIT_FAULT`` arms ``name`` for this call (see the module docstring)."""
    action = _armed(name)
    if action == "raise":
        raise InjectedFault(f"injected fault at {name} ({POINTS[name]})")
    if action is not None:
        signum = {"term": signal.SIGTERM, "int": signal.SIGINT, "kill": signal.SIGKILL}[action]
        os.kill(os.getpid(), signum)
