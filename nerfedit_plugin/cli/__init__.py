"""The ``nerfedit`` command line: one module per subcommand; :func:`main` (the console script) runs ``cli.app.main``."""

from __future__ import annotations

import signal
import sys
from typing import Any

_EARLY = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


def _stop_early(signum: int, frame: Any) -> None:
    sys.stderr.write(f"nerfedit: interrupted ({signal.Signals(signum).name}) while starting; nothing was written\n")
    raise SystemExit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    """The console script ``nerfedit``: a signal that arrives while the command line loads (before
    :func:`nerfedit_plugin.cli.app.main` installs its own handlers) ends it with one line and 128 + the signal's
    number, like an interrupt later on; then ``nerfedit_plugin.cli.app.main(argv)``."""
    if argv is None:  # the console script; a caller in Python keeps its own handlers
        for signum in _EARLY:
            if signal.getsignal(signum) not in (signal.SIG_IGN, None):
                signal.signal(signum, _stop_early)
    from nerfedit_plugin.cli.app import main as run

    return run(argv)


def __getattr__(name: str) -> Any:  # the subcommands' table without importing them up front
    if name == "COMMANDS":
        from nerfedit_plugin.cli import app

        return app.COMMANDS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
