"""nerfstudio-style configs: a dataclass whose ``_target`` is the class it builds (hidden from the CLI as a fixed
field), and writing a run's full config to YAML."""

from __future__ import annotations

import dataclasses
import enum
import numbers
import os
import types
import typing
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from nerfedit_plugin.errors import NerfEditError, OptionError
from nerfedit_plugin.io.atomic import write_text


@dataclasses.dataclass
class InstantiateConfig:
    """Base config: ``config.setup(**kwargs)`` builds ``config._target(config, **kwargs)``."""

    _target: type = dataclasses.field(default_factory=lambda: object)

    def setup(self, **kwargs: Any) -> Any:
        return self._target(self, **kwargs)


def to_plain(value: Any) -> Any:
    """Convert configs (nested dataclasses, paths, enums, arrays, classes) into YAML-safe builtins."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    if isinstance(value, (os.PathLike, Path)):
        return str(value)
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    return value


def _value_from_plain(tp: Any, value: Any) -> Any:
    """Inverse of :func:`to_plain` for one annotated value (dataclasses, paths, enums, tuples, optionals); a value of
    the wrong kind (text for a number, a choice not in a ``Literal``) is a ``ValueError`` saying what was expected."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return _value_from_plain(args[0], value)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        problems = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _value_from_plain(arg, value)
            except (TypeError, ValueError, OptionError) as exc:
                problems.append(exc.problem if isinstance(exc, OptionError) else str(exc))
        raise ValueError(" or ".join(dict.fromkeys(problems)) or f"unexpected value {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ValueError(f"expected one of {', '.join(map(repr, args))}, got {value!r}")
        return value
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ValueError(f"expected a mapping of {tp.__name__}'s options, got {value!r}")
        return from_plain(tp, value)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return tp(value)
    if isinstance(tp, type) and issubclass(tp, Path):
        return Path(_checked((str, os.PathLike), value, "a path"))
    if isinstance(tp, type) and issubclass(tp, np.ndarray):
        return np.asarray(value)
    if origin is tuple or origin is list:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"expected a list, got {value!r}")
        if origin is list:
            return [_value_from_plain(args[0] if args else Any, v) for v in value]
        items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args or (Any,) * len(value)
        if len(items) != len(value):
            raise ValueError(f"expected {len(items)} items, got {value!r}")
        return tuple(_value_from_plain(a, v) for a, v in zip(items, value))
    if tp is bool:
        return _checked(bool, value, "true or false")
    if tp is int:
        return int(_checked(numbers.Integral, value, "an integer"))
    if tp is float:
        if isinstance(value, str):  # YAML 1.1 reads 1e-6 (no dot) as text
            try:
                return float(value)
            except ValueError:
                pass
        return float(_checked(numbers.Real, value, "a number"))
    if tp is str:
        return _checked(str, value, "text")
    return value


def _checked(kind: type | tuple[type, ...], value: Any, expected: str) -> Any:
    """``value`` when it is a ``kind`` (a bool is not a number here), else a ``ValueError``."""
    if isinstance(value, kind) and (kind is bool or not isinstance(value, (bool, np.bool_))):
        return value
    raise ValueError(f"expected {expected}, got {value!r}")


def from_plain(cls: type, plain: dict, *, missing: Any = dataclasses.MISSING) -> Any:
    """Inverse of :func:`to_plain` for a config dataclass ``cls``: rebuild it from its plain (YAML) form. A field
    absent from ``plain`` takes its default (a config written before the field existed still loads); a required one
    takes ``missing`` when given (e.g. ``tyro.MISSING``), else the constructor's error is raised. A key that is no
    field, or a value of the wrong kind, is an :class:`~nerfedit_plugin.errors.OptionError` naming it."""
    try:
        hints = typing.get_type_hints(cls, include_extras=True)
    except Exception:  # unresolvable forward references (e.g. classes local to a test function)
        hints = {}
    unknown = sorted(set(plain) - {f.name for f in dataclasses.fields(cls)})  # to_plain writes init=False fields too
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    if unknown:
        options = ", ".join(sorted(n for n in fields if n != "_target"))
        raise OptionError(cls, unknown[0], f"unknown key (the options are: {options})")
    kwargs = {}
    for name in (n for n in fields if n != "_target" and n in plain):
        try:
            kwargs[name] = _value_from_plain(hints.get(name, Any), plain[name])
        except OptionError as exc:  # in a nested config: prefix this field
            raise OptionError(cls, f"{name}.{exc.option}", exc.problem) from None
        except (TypeError, ValueError) as exc:
            raise OptionError(cls, name, str(exc)) from None
    if missing is not dataclasses.MISSING:
        kwargs.update(
            {
                f.name: missing
                for f in fields.values()
                if f.name not in kwargs
                and f.default is dataclasses.MISSING
                and f.default_factory is dataclasses.MISSING
            }
        )
    return cls(**kwargs)


def write_config(path: str | os.PathLike, config: Any) -> None:
    """Write the full config of a run to YAML, atomically."""
    write_text(path, yaml.safe_dump(to_plain(config), sort_keys=False))


def read_config(path: str | os.PathLike, what: str) -> dict:
    """The mapping in the YAML file ``path``; a missing file or one that is not a YAML mapping is a
    :class:`~nerfedit_plugin.errors.NerfEditError` naming the file (``what`` says what was expected there)."""
    path = Path(path)
    if not path.is_file():
        raise NerfEditError(f"{path}: no such file ({what})")
    try:
        config = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, ValueError) as exc:  # ValueError: bad UTF-8, an integer of > 4300 digits
        raise NerfEditError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(config, dict):
        raise NerfEditError(f"{path}: expected a mapping ({what})")
    return config
