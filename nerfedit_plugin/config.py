"""nerfstudio-style configs: a dataclass whose ``_target`` is the class it builds (hidden from the CLI as a fixed
field), and writing a run's full config to YAML."""

from __future__ import annotations

import dataclasses
import enum
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .atomic import write_text


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


def write_config(path: str | os.PathLike, config: Any) -> None:
    """Write the full config of a run to YAML, atomically."""
    write_text(path, yaml.safe_dump(to_plain(config), sort_keys=False))
