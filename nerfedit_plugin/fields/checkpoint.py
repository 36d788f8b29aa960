"""Field checkpoints (``RUN_DIR/field.pt``): which backend, its config, the scene box and the state dict.

The file is a ``torch.save`` of plain data only — ``{"format", "backend", "config" (``to_plain`` of the config),
"scene_bbox", "state_dict"}`` — so it loads with ``torch.load(weights_only=True)`` (no pickled code runs). The
backend is the name of the config class's ``nerfedit.fields`` entry point; loading finds that entry point through
the registry, rebuilds the config, builds the field with ``config.setup(scene_bbox=...)`` and loads the state dict.
A missing or corrupt file, an unknown backend, or a checkpoint of another backend than the one requested raises
:class:`NerfEditError` naming the file. (The run's full config is written beside it as ``config.yml`` by the command
that made the run.)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from nerfedit_plugin.config import from_plain, to_plain
from nerfedit_plugin.errors import NerfEditError, OptionError
from nerfedit_plugin.io.atomic import atomic_path
from nerfedit_plugin.registry import FIELDS, Registry, discover

if TYPE_CHECKING:
    from nerfedit_plugin.fields.base import Field

CHECKPOINT_FORMAT = 1
"""Layout version of ``field.pt``."""


def backend_name(config_class: type, registry: Registry | None = None) -> str:
    """The ``nerfedit.fields`` entry-point name registered for ``config_class``."""
    registry = discover(FIELDS) if registry is None else registry
    for name, plugin in registry.plugins.get(FIELDS, {}).items():
        if plugin.config_class is config_class:
            return name
    raise NerfEditError(
        f"field config {config_class.__module__}.{config_class.__qualname__} is not registered in the {FIELDS} "
        "entry points; register it to save checkpoints"
    )


def save_field(field: Field, path: str | os.PathLike, registry: Registry | None = None) -> None:
    """Write ``field``'s checkpoint to ``path`` atomically (see the module docstring)."""
    payload = {
        "format": CHECKPOINT_FORMAT,
        "backend": backend_name(type(field.config), registry),
        "config": to_plain(field.config),
        "scene_bbox": field.scene_bbox.detach().cpu().tolist(),
        "state_dict": {k: v.detach().cpu() for k, v in field.state_dict().items()},
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def _read(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise NerfEditError(f"{path}: field checkpoint not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # zip, unpickling and EOF errors all mean "not a checkpoint"
        raise NerfEditError(f"{path}: not a readable field checkpoint ({type(exc).__name__}: {exc})") from exc
    keys = ("format", "backend", "config", "scene_bbox", "state_dict")
    if not isinstance(payload, dict) or any(key not in payload for key in keys):
        raise NerfEditError(f"{path}: not a field checkpoint (expected the keys {', '.join(keys)})")
    if payload["format"] != CHECKPOINT_FORMAT:
        raise NerfEditError(f"{path}: checkpoint format {payload['format']!r}, expected {CHECKPOINT_FORMAT}")
    return payload


def load_field(
    path: str | os.PathLike,
    registry: Registry | None = None,
    *,
    backend: str | None = None,
    expected: type | None = None,
    device: torch.device | str = "cpu",
) -> Field:
    """Load a checkpoint written by :func:`save_field`. ``backend`` (an entry-point name) or ``expected`` (a Field
    subclass) state what the caller wants; a checkpoint of anything else is an error, as is a missing/corrupt file
    or a backend the registry does not know."""
    path = Path(path)
    payload = _read(path)
    name = payload["backend"]
    if backend is not None and name != backend:
        raise NerfEditError(f"{path}: checkpoint of the {name!r} field backend, not {backend!r}")
    registry = discover(FIELDS) if registry is None else registry
    try:
        config_class = registry.config_class(FIELDS, name)
    except NerfEditError as exc:
        raise NerfEditError(f"{path}: {exc}") from exc
    target = config_class()._target
    if expected is not None and not issubclass(target, expected):
        raise NerfEditError(
            f"{path}: checkpoint of the {name!r} field backend ({target.__name__}), not {expected.__name__}"
        )
    try:
        config = from_plain(config_class, payload["config"])
        field = config.setup(scene_bbox=torch.tensor(payload["scene_bbox"], dtype=torch.float32))
        field.load_state_dict(payload["state_dict"])
    except OptionError as exc:  # a recorded option the backend does not have, or of the wrong kind
        raise NerfEditError(f"{path}: config.{exc.option}: {exc.problem}") from exc
    except NerfEditError:
        raise
    except Exception as exc:  # missing config keys, wrong tensor shapes: the file does not match the backend
        raise NerfEditError(
            f"{path}: checkpoint does not match the {name!r} backend ({type(exc).__name__}: {exc})"
        ) from exc
    return field.to(device)
