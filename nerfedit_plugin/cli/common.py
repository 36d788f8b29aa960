"""What the subcommands share: the one console, the two-pass parse (plugin choice, then tyro), ``--load-config``,
``--verbose``, the record written to ``config.yml``, and rich tables.

The parse of ``nerfedit COMMAND ARGS``:

1. a first pass reads ``--load-config FILE`` (commands that write a folder) and the plugin option (``--deformer``,
   ``--field``; default: the loaded config's choice, else the built-in default);
2. the command's args dataclass is extended by the chosen plugin's config (option group ``--deformer-options.*``)
   and the shared flags (``--load-config``, ``--verbose``, declared here once);
3. tyro parses ARGS, with the loaded config as defaults: flags given on the command line override it.

The help lists every installed plugin of the group with its one-line description: the first line of its config
class's docstring.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import inspect
import os
import pkgutil
import sys
import types
import typing
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Annotated, Any

import tyro
from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.table import Table

from nerfedit_plugin.config import from_plain, read_config
from nerfedit_plugin.errors import NerfEditError, OptionError
from nerfedit_plugin.registry import Registry, discover

console = Console(emoji=False)  # paths and messages print verbatim: "a:fire:b" is not an emoji
"""The console of every subcommand: results on stdout; :func:`print_error` and :func:`print_warning` write one line
to stderr."""

TYRO_CONFIG = (tyro.conf.SuppressFixed,)
CONFIG = "config.yml"

NOT_LOADED = frozenset({"load_config", "overwrite", "verbose"})
"""Recorded args that ``--load-config`` never takes from the file: they are about one invocation, not the work
(a re-run never replaces a folder unless ``--overwrite`` is given again)."""

PATH_STRINGS = frozenset({"mesh", "objects"})
"""``str`` args (or tuples of them) that name files unless they are ``sample:NAME`` or ``shape:NAME`` (recorded
absolute, like ``Path`` args)."""

LOAD_CONFIG = (
    "load_config",
    Annotated[
        Path | None,
        tyro.conf.arg(
            help="Re-run a recorded command: the config.yml of its output folder (or the folder) gives every option; "
            "flags given on the command line override it. Relative paths in the file are resolved against the current "
            "folder (nerfedit records them absolute)."
        ),
    ],
    dataclasses.field(default=None),
)
VERBOSE = (
    "verbose",
    Annotated[bool, tyro.conf.arg(help="Show tracebacks for errors.")],
    dataclasses.field(default=False),
)
"""The flags every subcommand shares (``--load-config`` those that record), appended by :func:`parse`."""


@dataclasses.dataclass(frozen=True)
class Command:
    """One subcommand: ``run(args)`` with ``args`` an instance of ``args`` (as extended by :func:`parse`)."""

    name: str
    args: type
    run: Callable[[Any], None]
    plugin: tuple[str, str, str] | None = None
    """``(option, entry point group, default name)`` of the plugin chosen in the first pass."""
    records: bool = False
    """Writes a folder with ``config.yml`` (the parsed args): takes ``--load-config``."""


def _option(argv: list[str], name: str) -> str | None:
    """Value of ``--name VALUE`` / ``--name=VALUE`` in ``argv`` (first pass of the two-pass parse)."""
    for i, arg in enumerate(argv):
        if arg == f"--{name}" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(f"--{name}="):
            return arg.split("=", 1)[1]
    return None


def describe(config_class: type) -> str:
    """A plugin's one-line description: the first line of its config class's docstring."""
    doc = inspect.getdoc(config_class) or ""
    if doc.startswith(f"{config_class.__name__}("):  # the signature dataclasses write when there is no docstring
        return ""
    return doc.splitlines()[0] if doc else ""


def plugin_list(registry: Registry, group: str, option: str, chosen: str | None = None) -> str:
    """The help text listing the plugins of ``group``, ``chosen`` marked with ``*``."""
    found = registry.plugins.get(group, {})
    width = max(map(len, found), default=0)
    lines = [f"{group.split('.')[-1]} (--{option} NAME; * the chosen one, whose options are --{option}-options.*):"]
    lines += [
        f"  {'*' if name == chosen else ' '} {name:<{width}}  {describe(found[name].config_class)}"
        for name in sorted(found)
    ]
    skipped = sorted(s.name for s in registry.skipped if s.group == group)
    if skipped:
        lines.append(f"  skipped (broken, see `nerfedit plugins`): {', '.join(skipped)}")
    return "\n".join(lines)


def _extend(base: type, fields: list[tuple]) -> type:
    """``base`` with ``fields`` appended (after its own, so they come last in the help)."""
    args = dataclasses.make_dataclass(base.__name__, fields, bases=(base,))
    args.__doc__, args.__module__ = base.__doc__, base.__module__
    return args


def read_recorded(path: Path, command: str) -> tuple[Path, dict]:
    """The args recorded in a ``config.yml`` (or a folder holding one), without :data:`NOT_LOADED`. A run's file
    holds them under ``command``; one written without (``nerfedit demo``'s run) gives its field, data and config."""
    file = path / CONFIG if path.is_dir() else path
    plain = read_config(file, f"--load-config: a config.yml of `nerfedit {command}`")
    if isinstance(plain.get("command"), dict):
        plain = plain["command"]
    elif {"field", "data", "field_config"} <= plain.keys() and command == "train":
        plain = {
            "field": plain["field"],
            "data": str(file.parent / plain["data"]),
            "field_options": plain["field_config"],
        }
    return file, {k: v for k, v in plain.items() if k not in NOT_LOADED}


def _check_target(file: Path, key: str, plain: Any, config_class: type) -> None:
    """Warn when the recorded ``_target`` of a plugin config is not the class the plugin builds today."""
    recorded = plain.get("_target") if isinstance(plain, dict) else None
    target = config_class()._target
    if isinstance(recorded, str) and _import(recorded) is not target:
        print_warning(
            f"{file}: {key}._target {recorded} is not {target.__module__}.{target.__qualname__}, "
            "which the plugin builds now; using it"
        )


def _import(name: str) -> Any:
    """The object at a dotted path (``module.qualname``); ``None`` when it does not import."""
    try:
        return pkgutil.resolve_name(name)
    except (ImportError, AttributeError, ValueError):
        return None


def parse(command: Command, argv: list[str]) -> Any:
    """The parsed args of ``nerfedit COMMAND ARGV`` (see the module docstring)."""
    base, description, fields = command.args, command.args.__doc__ or "", []
    source = _option(argv, "load-config") if command.records else None
    file, loaded = read_recorded(Path(source), command.name) if source is not None else (None, {})
    if command.plugin is not None:
        option, group, default = command.plugin
        key, registry = f"{option}_options", discover(group)
        name = _option(argv, option) or loaded.get(option) or default
        config_class = registry.config_class(group, name)
        fields.append((key, config_class, dataclasses.field(default_factory=config_class)))
        description += "\n\n" + plugin_list(registry, group, option, name)
        if loaded.get(option, default) != name:
            loaded.pop(key, None)  # the file's options are another plugin's
        elif key in loaded:
            _check_target(file, key, loaded[key], config_class)
    args = _extend(base, [*fields, LOAD_CONFIG, VERBOSE] if command.records else [*fields, VERBOSE])
    default = tyro.MISSING_NONPROP
    groups = option_groups(args)
    if file is not None:
        unknown = sorted(set(loaded) - {f.name for f in dataclasses.fields(args)})
        if unknown:
            raise NerfEditError(
                f"{file}: not a config.yml of `nerfedit {command.name}` (unknown keys: {', '.join(unknown)})"
            )
        try:
            default = from_plain(args, loaded, missing=tyro.MISSING)
        except OptionError as exc:
            raise NerfEditError(f"{file}: {groups.get(exc.config_class, '')}{exc.option}: {exc.problem}") from exc
        except (TypeError, ValueError) as exc:
            raise NerfEditError(f"{file}: {exc}") from exc
    try:
        with _one_line_instantiation_errors(groups):
            return tyro.cli(
                args,
                args=argv,
                prog=f"nerfedit {command.name}",
                description=description,
                default=default,
                config=TYRO_CONFIG,
            )
    except OptionError as exc:
        raise NerfEditError(f"{flag(groups.get(exc.config_class, '') + exc.option)}: {exc.problem}") from exc
    except (TypeError, ValueError) as exc:  # a config's constructor rejected the values (a safety net)
        group = _raised_by(exc, groups)
        if group is None:
            raise
        raise NerfEditError(f"{_group_name(group)}: {exc}") from exc


def flag(option: str) -> str:
    """The command-line flag of an option path (tyro's spelling): ``field_options.train.batch_rays`` →
    ``--field-options.train.batch-rays``."""
    return "--" + option.replace("_", "-")


def option_groups(args: type, prefix: str = "") -> dict[type, str]:
    """``{config class: option prefix}`` of the dataclass ``args`` and of every nested config dataclass in it:
    ``{TrainArgs: "", NerfConfig: "field_options.", TrainerConfig: "field_options.train."}`` (the first place a class
    appears wins)."""
    found = {args: prefix}
    for base in args.__mro__[1:]:
        if dataclasses.is_dataclass(base):
            found.setdefault(base, prefix)
    try:
        hints = typing.get_type_hints(args)
    except Exception:  # unresolvable annotations (e.g. classes local to a test): the field's own type
        hints = {}
    for field in dataclasses.fields(args):
        kind = hints.get(field.name, field.type)
        candidates = typing.get_args(kind) if typing.get_origin(kind) in (typing.Union, types.UnionType) else (kind,)
        for candidate in candidates:
            if isinstance(candidate, type) and dataclasses.is_dataclass(candidate) and candidate not in found:
                found.update(
                    {k: v for k, v in option_groups(candidate, f"{prefix}{field.name}.").items() if k not in found}
                )
    return found


def _group_name(prefix: str) -> str:
    """How an error names an option group: ``--field-options`` (the options of the command itself: ``options``)."""
    return flag(prefix.rstrip(".")) if prefix else "options"


def _raised_by(exc: BaseException, groups: dict[type, str]) -> str | None:
    """The option prefix of the config whose constructor (``__init__``/``__post_init__``, the innermost one) raised
    ``exc`` or the exception it was raised while handling; None when no config constructor is on the traceback."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        found, tb = None, exc.__traceback__
        while tb is not None:
            frame = tb.tb_frame
            owner = frame.f_locals.get("self") if frame.f_code.co_name in ("__init__", "__post_init__") else None
            if owner is not None and type(owner) in groups:
                found = groups[type(owner)]
            tb = tb.tb_next
        if found is not None:
            return found
        exc = exc.__cause__ or exc.__context__
    return None


@contextlib.contextmanager
def _one_line_instantiation_errors(groups: dict[type, str]) -> Iterator[None]:
    """While tyro parses: a ValueError of a config's constructor, which tyro would report in a box, becomes a
    :class:`NerfEditError` naming the option group (through tyro's parse-error hook, when this tyro has it)."""
    try:
        errors = importlib.import_module("tyro._errors")
        hook, failure = errors.on_parse_error, errors.InstantiationFailure
    except (ImportError, AttributeError):
        yield
        return

    def handle(event: Any) -> None:
        if isinstance(event, failure):
            raised = sys.exc_info()[1]
            group = _raised_by(raised, groups) if raised is not None else None
            if group is None and isinstance(getattr(raised, "arg", None), str):  # tyro's InstantiationError
                group = raised.arg + "."
            if group is not None:
                raise NerfEditError(f"{_group_name(group)}: {event.message}")

    with hook(handle):
        yield


def recorded(args: Any) -> Any:
    """``args`` as ``config.yml`` records them: top-level paths (``Path`` values and :data:`PATH_STRINGS`) made
    absolute, so ``--load-config`` re-runs from any folder."""

    def absolute(value: str) -> str:
        return value if value.startswith(("sample:", "shape:")) else os.path.abspath(value)

    changes = {}
    for field in dataclasses.fields(args):
        value = getattr(args, field.name)
        if isinstance(value, Path):
            changes[field.name] = Path(os.path.abspath(value))
        elif field.name in PATH_STRINGS and isinstance(value, str):
            changes[field.name] = absolute(value)
        elif field.name in PATH_STRINGS and isinstance(value, tuple):  # e.g. generate --objects
            changes[field.name] = tuple(absolute(v) if isinstance(v, str) else v for v in value)
    return dataclasses.replace(args, **changes)


def print_error(message: Any) -> None:
    """One red line on stderr (the message verbatim: ``[nan, 0.0]`` is text, not rich markup)."""
    _to_stderr(f"[red]error:[/] {escape(str(message))}")


def print_warning(message: Any) -> None:
    """One yellow line on stderr (the message verbatim)."""
    _to_stderr(f"[yellow]warning:[/] {escape(str(message))}")


def _to_stderr(text: str) -> None:
    console.stderr = True
    try:
        console.print(text, highlight=False, soft_wrap=True)
    finally:
        console.stderr = False


def print_table(
    title: str,
    columns: Iterable[str],
    rows: Iterable[Iterable[Any]],
    *,
    justify: str = "right",
    overflow: str = "ellipsis",
    **table: Any,
) -> None:
    """A rich table of ``rows`` (cells are printed with ``str``): fitted to a terminal's width, at its natural width
    into a file or pipe (no cell cut mid-word for want of a terminal)."""
    out = Table(title=title, **table)
    for column in columns:
        out.add_column(column, justify=justify, overflow=overflow)
    for row in rows:
        out.add_row(*map(str, row))
    if not console.is_terminal:
        out.width = max(console.width, Measurement.get(console, console.options.update_width(10_000), out).maximum)
    console.print(out, crop=False)
