"""The coarse level a deformer binds on a large mesh: its options (a config mixin) and its bind-cache entry.

Deformers whose bind or solve grows faster than the mesh (ARAP's solve, bone heat) work on a vertex clustering of
the surface (:func:`~nerfedit_plugin.geometry.multires.coarse_level`) and carry the fine surface from it. The level
depends on the rest mesh and ``coarse_vertices`` only, so every such deformer shares one cache entry per mesh.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from nerfedit_plugin.edit.deformer import BindCache
from nerfedit_plugin.errors import check_option
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.multires import CoarseLevel, coarse_level, identity_level

MULTIRES_ABOVE = 60_000
"""The default of :attr:`CoarseOptions.coarse_above` (docs/benchmarks.md, "Edits at scale")."""
LEVEL_FORMAT = 1
"""Version of the coarse level kept in the bind cache (part of its key)."""


@dataclasses.dataclass
class CoarseOptions:
    """The options of a deformer that may bind on a coarse level (a dataclass mixin of its config)."""

    multiresolution: Literal["auto", "on", "off"] = "auto"
    """``on``: bind on a coarse level of the surface (vertex clustering) and carry the fine surface from it; ``off``:
    bind on the mesh itself; ``auto``: ``on`` for meshes of more than ``coarse_above`` vertices."""
    coarse_above: int = MULTIRES_ABOVE
    """``multiresolution = "auto"``: meshes of more vertices than this (a vertex count) bind on the coarse level."""
    coarse_vertices: int = 30_000
    """Vertex count (a number of vertices) aimed at for the coarse level; the clustering lands within about 10 % of
    it. At or above the mesh's own count the coarse level is the mesh."""

    def check_coarse_options(self) -> None:
        choice = self.multiresolution
        check_option(self, "multiresolution", choice, choice in ("auto", "on", "off"), "'auto', 'on' or 'off'")
        check_option(self, "coarse_vertices", self.coarse_vertices, self.coarse_vertices >= 3, ">= 3")
        check_option(self, "coarse_above", self.coarse_above, self.coarse_above >= 0, ">= 0")

    def binds_coarse(self, mesh: SurfaceMesh) -> bool:
        """Whether ``mesh`` is bound on a coarse level under these options."""
        return self.multiresolution == "on" or (self.multiresolution == "auto" and mesh.n_vertices > self.coarse_above)


def cached_coarse_level(cache: BindCache, mesh: SurfaceMesh, vertices: int) -> tuple[CoarseLevel, bool]:
    """``(level, hit)``: the coarse level of ``mesh`` at about ``vertices`` vertices, read from ``cache`` when stored
    there (``hit``), else clustered and stored; ``vertices`` ≥ the mesh's count gives the mesh itself (not stored)."""
    if vertices >= mesh.n_vertices:
        return identity_level(mesh), False
    params = {"coarse_vertices": vertices, "format": LEVEL_FORMAT}
    arrays, hit = cache.fetch("coarse-level", params, lambda: coarse_level(mesh, vertices).arrays())
    return CoarseLevel.from_arrays(arrays), hit
