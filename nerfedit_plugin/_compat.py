"""Module paths before the stage layout (0.1.0), kept importable for one release.

``import nerfedit_plugin.deformation_field`` (or a ``config.yml`` whose ``_target`` names an old path) gets the module
at its new home, with a :class:`DeprecationWarning`; docs/architecture.md lists the moves.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

MOVED = {
    "arap": "geometry.arap",
    "atomic": "io.atomic",
    "bend_kernel": "bending._bend_kernel",
    "cameras": "data.cameras",
    "checkpoint": "io.checkpoint",
    "datasets": "data.datasets",
    "deformation_field": "bending.deformation_field",
    "deformer": "edit.deformer",
    "editspec": "edit.spec",
    "field": "fields.base",
    "lift": "edit.lift",
    "locate": "bending.locate",
    "locate_kernel": "bending._locate_kernel",
    "mesh": "geometry.mesh",
    "metrics": "training.metrics",
    "proxy": "edit.proxy",
    "renderer": "render.renderer",
    "run": "io.run",
    "samples": "io.samples",
    "synthetic": "data.synthetic",
    "testing_fields": "testing.fields",
    "trainer": "training.trainer",
    "viewer": "viewer.layers",
    "views": "render.views",
}
"""old module name -> new module, both relative to ``nerfedit_plugin``. The old modules ``edit``, ``cli`` and
``testing`` are packages now that re-export what they held (``edit.run_edit``, ``cli.main``, the deformer kit)."""

_PACKAGE = __name__.rsplit(".", 1)[0]

MOVED_PLUGINS = {
    "deformers.mean_value": "deformers.cage.mean_value",
    "deformers.green": "deformers.cage.green",
    "deformers.bvh": "deformers.skeleton.bvh",
    "deformers.skinning": "deformers.skeleton.skinning",
    "deformers.heat_weights": "deformers.skeleton.heat_weights",
}
"""Built-in deformer modules that moved into their plugin's folder (absolute names). ``deformers.cage`` and
``deformers.skeleton`` are packages now that re-export what the modules held."""


def _new_name(fullname: str) -> str | None:
    prefix, _, name = fullname.rpartition(".")
    if prefix == _PACKAGE and name in MOVED:
        return f"{_PACKAGE}.{MOVED[name]}"
    return MOVED_PLUGINS.get(fullname)


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module) -> None:
        pass


class _AliasFinder(importlib.abc.MetaPathFinder):
    """Resolves the old names of :data:`MOVED` and :data:`MOVED_PLUGINS` to their new modules."""

    def find_spec(self, fullname, path=None, target=None):
        new = _new_name(fullname)
        if new is None:
            return None
        warnings.warn(
            f"{fullname} moved to {new}; the old path goes away in the next release", DeprecationWarning, stacklevel=2
        )
        return importlib.util.spec_from_loader(fullname, _AliasLoader(new))


def install() -> None:
    """Register the alias finder once (called by ``nerfedit_plugin/__init__``)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.append(_AliasFinder())
