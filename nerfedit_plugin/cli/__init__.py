"""The ``nerfedit`` command line: one module per subcommand; :func:`main` dispatches."""

import importlib
from typing import Any


def __getattr__(name: str) -> Any:  # ``nerfedit_plugin.cli:main`` without importing every subcommand up front
    if name in ("main", "COMMANDS"):
        return getattr(importlib.import_module("nerfedit_plugin.cli.app"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
