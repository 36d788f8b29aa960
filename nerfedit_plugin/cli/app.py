"""``nerfedit`` command line (tyro): :func:`main` dispatches to one module per subcommand.

Each module (``cli/train.py``, ``cli/edit.py``, …) holds its args dataclass, its function and its
:class:`~nerfedit_plugin.cli.common.Command`; :mod:`nerfedit_plugin.cli.common` parses (plugin choice, then tyro,
``--load-config``) and holds the one console. ``nerfedit --help`` lists the subcommands with one line each (the first
sentence of their args dataclass's docstring, read from the source: no subcommand is imported for it);
``nerfedit`` alone prints the same to stderr and exits 2. ``nerfedit SUBCOMMAND --help`` lists the options of each
subcommand. User errors print one line and exit 2; ``--verbose`` (read from the parsed args) shows the traceback.
An interrupt (SIGINT, SIGTERM, SIGHUP) prints one line saying what was kept and exits 128 + the signal's number
(130, 143, 129); staging folders are removed on the way out (see :mod:`nerfedit_plugin.io.atomic`).
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import signal
import sys
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from nerfedit_plugin.cli.common import Command

COMMANDS: dict[str, str] = {
    "train": "train",
    "extract": "extract",
    "edit": "edit",
    "render": "render",
    "export": "export",
    "eval": "evaluate",
    "view": "view",
    "generate": "generate",
    "process": "process",
    "demo": "demo",
    "plugins": "plugins",
}
"""subcommand -> its module in ``nerfedit_plugin.cli`` (imported when the subcommand runs: startup stays fast)."""

USAGE = "usage: nerfedit {" + ",".join(COMMANDS) + "} [--help]"
SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
"""The signals :func:`main` turns into :class:`Interrupted` (each unless its handler is SIG_IGN, e.g. under nohup)."""


class Interrupted(KeyboardInterrupt):
    """Raised by the signal handlers of :func:`main`: a ``KeyboardInterrupt``, so every cleanup runs."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def command(name: str) -> Command:
    """The :class:`Command` of subcommand ``name``."""
    return importlib.import_module(f"nerfedit_plugin.cli.{COMMANDS[name]}").COMMAND


def description(name: str) -> str:
    """One line on what subcommand ``name`` does: the first sentence of its args dataclass's docstring (the part
    before a colon when that sentence is long), read from the source with :mod:`ast` (no import: ``--help`` stays
    fast)."""
    package = Path(__file__).resolve().parents[1]
    tree = ast.parse((package / "cli" / f"{COMMANDS[name]}.py").read_text())
    args = next(
        node.value.args[1].id
        for node in tree.body
        if isinstance(node, ast.Assign)
        and any(isinstance(target, ast.Name) and target.id == "COMMAND" for target in node.targets)
    )
    for _ in range(3):  # the class, or the module it is imported from
        found = next((node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == args), None)
        if found is not None:
            return _first_sentence(ast.get_docstring(found) or "")
        module = next(
            node.module
            for node in tree.body
            if isinstance(node, ast.ImportFrom) and any(alias.name == args for alias in node.names)
        )
        tree = ast.parse((package.parent / (module.replace(".", "/") + ".py")).read_text())
    return ""


def _first_sentence(doc: str) -> str:
    text = " ".join(doc.split("\n\n")[0].split())
    sentence = text.split(". ")[0].rstrip(".")
    if len(sentence) > 120 and ": " in sentence:  # one line in a wide terminal
        sentence = sentence.split(": ")[0]
        if sentence.count("(") > sentence.count(")"):  # cut inside a parenthesis: drop it
            sentence = sentence[: sentence.rindex("(")].rstrip(" ,;")
    return sentence + "."


def overview() -> str:
    """The usage line and every subcommand with its description."""
    width = max(map(len, COMMANDS))
    lines = [USAGE, "", "commands:"]
    lines += [f"  {name:<{width}}  {description(name)}" for name in COMMANDS]
    lines += ["", "`nerfedit COMMAND --help` lists the options of a command."]
    return "\n".join(lines)


@contextlib.contextmanager
def interrupts_raise() -> Iterator[list[int]]:
    """Within the block, SIGINT/SIGTERM/SIGHUP raise :class:`Interrupted` (in the main thread; signals that are
    ignored stay ignored). The previous handlers come back afterwards. Yields the signals received, so a caller can
    tell an interrupt that library code swallowed (trimesh's optional imports catch BaseException)."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        received.append(signum)
        raise Interrupted(signum)

    previous = {}
    for signum in SIGNALS:
        if signal.getsignal(signum) not in (signal.SIG_IGN, None):
            previous[signum] = signal.signal(signum, handler)
    try:
        yield received
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def _interrupted(name: str, exc: KeyboardInterrupt, since: int) -> int:
    """Print the one line of an interrupted command; its exit code (128 + the signal)."""
    from nerfedit_plugin.io import atomic

    signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
    kept = list(dict.fromkeys(path for path in atomic.committed[since:] if path.exists()))
    parts = []
    for label, paths in (
        ("complete", [p for p in kept if not atomic.is_partial(p)]),
        ("partial", [p for p in kept if atomic.is_partial(p)]),
    ):
        if paths:
            more = f" and {len(paths) - 3} more" if len(paths) > 3 else ""
            parts.append(f"kept ({label}): " + ", ".join(map(str, paths[:3])) + more)
    what = "; ".join(parts) or "nothing written"
    with contextlib.suppress(OSError):  # e.g. SIGHUP: the terminal is gone
        sys.stderr.write(f"nerfedit {name}: interrupted ({signal.Signals(signum).name}); {what}\n")
        sys.stderr.flush()
    return 128 + int(signum)


def main(argv: list[str] | None = None) -> int:
    """``nerfedit ARGV`` (default: ``sys.argv[1:]``, as the console script runs it) → exit code."""
    from_console = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(overview(), file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print(overview())
        return 0
    if argv[0] not in COMMANDS:
        from nerfedit_plugin.cli.common import print_error

        print_error(f"unknown command {argv[0]!r} ({USAGE}; `nerfedit --help` says what each does)")
        return 2
    from nerfedit_plugin.io import atomic  # before the handlers (the console script's own cover its imports)

    since, args = len(atomic.committed), None
    try:
        with interrupts_raise() as received:
            from nerfedit_plugin.cli.common import parse, print_error, print_warning
            from nerfedit_plugin.errors import NerfEditError

            spec = command(argv[0])
            try:
                args = parse(spec, argv[1:])
                with warnings.catch_warnings():  # a UserWarning is one line for the user, like an error
                    shown = warnings.showwarning

                    def show(message, category, *rest, **options):
                        if issubclass(category, UserWarning):
                            print_warning(message)
                        else:  # deprecations and the like: as Python's filters decide
                            shown(message, category, *rest, **options)

                    warnings.showwarning = show
                    spec.run(args)
                if received:  # an interrupt some library swallowed: the command ran on, but it was interrupted
                    raise Interrupted(received[-1])
            except NerfEditError as exc:
                if getattr(args, "verbose", False):
                    raise
                print_error(exc)
                return 2
    except KeyboardInterrupt as exc:
        if getattr(args, "verbose", False):
            import traceback

            traceback.print_exc()
        return _interrupted(argv[0], exc, since)
    except Exception as exc:  # an interrupt that library code (an import, a kernel) wrapped in its own error
        interrupt = _interrupt_in_chain(exc)
        if interrupt is None or getattr(args, "verbose", False):
            raise
        return _interrupted(argv[0], interrupt, since)
    if from_console:  # done and committed: a signal during the interpreter's shutdown must not fail the command
        for signum in SIGNALS:
            if signal.getsignal(signum) not in (signal.SIG_IGN, None):
                signal.signal(signum, signal.SIG_IGN)
    return 0


def _interrupt_in_chain(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (or :class:`Interrupted`) ``exc`` was raised while handling, if any."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


if __name__ == "__main__":
    sys.exit(main())
