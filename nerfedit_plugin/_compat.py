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


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module) -> None:
        pass


class _AliasFinder(importlib.abc.MetaPathFinder):
    """Resolves ``nerfedit_plugin.<old>`` to ``nerfedit_plugin.<new>`` for the names in :data:`MOVED`."""

    def find_spec(self, fullname, path=None, target=None):
        prefix, _, name = fullname.rpartition(".")
        if prefix != _PACKAGE or name not in MOVED:
            return None
        new = f"{_PACKAGE}.{MOVED[name]}"
        warnings.warn(f"{fullname} moved to {new}; the old path goes away in the next release",
                      DeprecationWarning, stacklevel=2)
        return importlib.util.spec_from_loader(fullname, _AliasLoader(new))


def install() -> None:
    """Register the alias finder once (called by ``nerfedit_plugin/__init__``)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.append(_AliasFinder())
