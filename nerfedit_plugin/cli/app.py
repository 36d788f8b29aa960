"""``nerfedit`` command line (tyro): :func:`main` dispatches to one module per subcommand.

Each module (``cli/train.py``, ``cli/edit.py``, …) holds its args dataclass, its function and its
:class:`~nerfedit_plugin.cli.common.Command`; :mod:`nerfedit_plugin.cli.common` parses (plugin choice, then tyro,
``--load-config``) and holds the one console. ``nerfedit SUBCOMMAND --help`` lists the options of each subcommand.
User errors print one line and exit 2; ``--verbose`` (read from the parsed args) shows the traceback.
"""

from __future__ import annotations

import importlib
import sys

from nerfedit_plugin.cli.common import Command, console, parse, print_error
from nerfedit_plugin.errors import NerfEditError

COMMANDS: dict[str, str] = {
    "train": "train",
    "extract": "extract",
    "edit": "edit",
    "render": "render",
    "eval": "evaluate",
    "view": "view",
    "generate": "generate",
    "demo": "demo",
    "plugins": "plugins",
}
"""subcommand -> its module in ``nerfedit_plugin.cli`` (imported when the subcommand runs: startup stays fast)."""


def command(name: str) -> Command:
    """The :class:`Command` of subcommand ``name``."""
    return importlib.import_module(f"nerfedit_plugin.cli.{COMMANDS[name]}").COMMAND


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    usage = "usage: nerfedit {" + ",".join(COMMANDS) + "} [--help]"
    if not argv or argv[0] in ("-h", "--help"):
        console.print(usage, highlight=False)
        return 0
    if argv[0] not in COMMANDS:
        print_error(f"unknown command {argv[0]!r} ({usage})")
        return 2
    spec, args = command(argv[0]), None
    try:
        args = parse(spec, argv[1:])
        spec.run(args)
    except NerfEditError as exc:
        if getattr(args, "verbose", False):
            raise
        print_error(exc)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
