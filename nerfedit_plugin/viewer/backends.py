"""The editor's backend of a deformer, found through the registry: the
:class:`~nerfedit_plugin.edit.editing.EditingBackend` subclass its Deformer names in
:attr:`~nerfedit_plugin.edit.deformer.Deformer.editor` (the same for a built-in and a third-party plugin)."""

from __future__ import annotations

from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.edit.editing import EditingBackend
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import DEFORMERS, discover


def backend_class(name: str, config: DeformerConfig) -> type[EditingBackend]:
    """The backend class of deformer ``name`` (configured by ``config``); an error naming it when it offers none."""
    target = config._target
    backend = target.editor
    if backend is None:
        raise NerfEditError(
            f"view: deformer {name!r} offers no editor backend ({target.__name__}.editor is None), so it cannot be"
            f" edited in the viewer; write its spec and run `nerfedit edit --deformer {name}`"
        )
    if not (isinstance(backend, type) and issubclass(backend, EditingBackend)):
        raise NerfEditError(f"view: deformer {name!r}: {target.__name__}.editor is {backend!r}, not an EditingBackend")
    return backend


def editing_backend(name: str, rest: SurfaceMesh, keys: dict | None = None, config: DeformerConfig | None = None):
    """The backend of deformer ``name`` (its registry config's defaults unless ``config``) on ``rest``; ``keys``: the
    deformer's own spec keys (:attr:`~nerfedit_plugin.edit.editing.EditingBackend.own_keys`), file paths as
    :class:`~pathlib.Path` (absolute)."""
    config = config or discover(DEFORMERS).config_class(DEFORMERS, name)()
    cls = backend_class(name, config)
    for key in keys or {}:
        if key not in cls.own_keys:
            raise NerfEditError(f"view: --{key} does not go with --deformer {name} (its handles grab {cls.what})")
    return cls(rest, config, keys or {})
