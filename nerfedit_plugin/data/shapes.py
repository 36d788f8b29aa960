"""The generated benchmark objects, ``shape:NAME`` for :func:`nerfedit_plugin.data.synthetic.generate_dataset`: each
is hard for a field in its own way.

- ``tube``: a thin rod along a 3-D S curve (diameter 0.048, length ~1.8: ~3.7 px thick at 100×100);
- ``cup``: an open cup, a solid of revolution with a deep cavity (wall 5 % of the height);
- ``slab``: a tilted book-like plate whose two large flat faces cover ~2/3 of its area;
- ``bunny-fine``: the pymeshlab bunny, refined, with a texture of 2.5× the default frequency (checker cells 1/15 of
  the bunny's length: ~3.5 px at 100×100, where the default's are ~9 px).

Every mesh is watertight, deterministic and built y-up (the generator's default ``up_axis``) in the generator's
frame (bounding box centred at the origin, longest side 1), with edges short enough for per-vertex colours to
carry the texture. ``tube``, ``cup`` and ``slab`` are marching cubes (scikit-image) of analytic signed distances.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh, longest_side_frame

PREFIX = "shape:"
CELL = 1.0 / 128
"""Marching-cubes lattice spacing in the generator's frame (~0.5 px at 100×100)."""
TUBE_RADIUS = 0.025
"""Radius of the tube (before the final rescaling to a longest side of 1)."""
CUP_WALL = 0.05
"""Wall and bottom thickness of the cup, as a fraction of its height."""
SLAB_SIZE = (1.0, 0.7, 0.12)
"""Sides of the slab before it is tilted."""
FINE_EDGE = 0.0075
"""Longest edge of the refined bunny (the fine checker's cells are 1/15 wide)."""


@dataclass(frozen=True)
class Shape:
    """A benchmark object: how to build its mesh and the texture frequency the generator colours it with."""

    build: Callable[[], SurfaceMesh]
    """Returns the mesh (no colours), in the generator's frame."""
    texture_frequency: float = 1.0
    """The ``frequency`` of :func:`nerfedit_plugin.data.synthetic.colorize`."""


def _unit_frame(mesh: SurfaceMesh) -> SurfaceMesh:
    """``mesh`` with its bounding box centred at the origin and its longest side scaled to 1."""
    centre, extent = longest_side_frame(mesh.vertices)
    return mesh.with_vertices((mesh.vertices - centre) / extent)


def level_set_mesh(sdf: Callable[[np.ndarray], np.ndarray], low, high, cell: float) -> SurfaceMesh:
    """The zero level set of ``sdf`` (points (..., 3) → signed distances, negative inside) sampled every ``cell``
    inside the box ``[low, high]`` (padded by two cells, so the surface is closed): scikit-image marching cubes,
    faces counter-clockwise seen from outside."""
    from skimage.measure import marching_cubes

    low, high = np.asarray(low, dtype=np.float64) - 2 * cell, np.asarray(high, dtype=np.float64) + 2 * cell
    axes = [np.arange(lo, hi + cell, cell) for lo, hi in zip(low, high)]
    values = sdf(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1))
    vertices, faces, _, _ = marching_cubes(-values, 0.0, spacing=(cell,) * 3)
    return SurfaceMesh(vertices + low, faces[:, ::-1].astype(np.int64))


def _marching_cubes(sdf: Callable[[np.ndarray], np.ndarray], low, high) -> SurfaceMesh:
    """:func:`level_set_mesh` at :data:`CELL`, in the generator's frame."""
    return _unit_frame(level_set_mesh(sdf, low, high, CELL))


def _segment_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance from ``points (..., D)`` to the polyline ``(K, D)``."""
    best = np.full(points.shape[:-1], np.inf)
    for a, b in zip(polyline[:-1], polyline[1:]):
        t = np.clip(((points - a) @ (b - a)) / float((b - a) @ (b - a)), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[..., None] * (b - a)), axis=-1))
    return best


def tube() -> SurfaceMesh:
    """A rod of radius :data:`TUBE_RADIUS` with round ends around the curve ``(0.5 t, 0.2 sin πt, 0.15 sin 2πt)``,
    ``t ∈ [−1, 1]`` (an S bending out of its plane)."""
    from scipy.spatial import cKDTree

    t = np.linspace(-1.0, 1.0, 1001)  # samples 0.0015 apart: the distance to them is the curve's within 2e-5
    curve = np.stack([0.5 * t, 0.2 * np.sin(np.pi * t), 0.15 * np.sin(2 * np.pi * t)], axis=1)
    tree = cKDTree(curve)

    def sdf(points: np.ndarray) -> np.ndarray:
        far = TUBE_RADIUS + 3 * CELL  # farther points only need a positive value
        distance = tree.query(points.reshape(-1, 3), distance_upper_bound=far)[0]
        return np.minimum(distance, far).reshape(points.shape[:-1]) - TUBE_RADIUS

    return _marching_cubes(sdf, curve.min(0) - TUBE_RADIUS, curve.max(0) + TUBE_RADIUS)


def cup() -> SurfaceMesh:
    """An open cup of height 1 along +y: the wall's mid-line (bottom disc, then a flared side from radius 0.3 to
    0.4) thickened by :data:`CUP_WALL` and revolved; the rim is rounded."""
    half = CUP_WALL / 2
    profile = np.array([[0.0, half], [0.3, half], [0.4, 1.0 - half]])  # (radius, height) of the mid-line

    def sdf(points: np.ndarray) -> np.ndarray:
        radial = np.stack([np.hypot(points[..., 0], points[..., 2]), points[..., 1]], axis=-1)
        return _segment_distance(radial, profile) - half

    return _marching_cubes(sdf, [-0.4 - half, 0.0, -0.4 - half], [0.4 + half, 1.0, 0.4 + half])


def slab() -> SurfaceMesh:
    """A box of sides :data:`SLAB_SIZE` with edges rounded by a quarter of its thickness, tilted by 30° about x and
    20° about z, so its large faces are planes no axis view sees edge-on."""
    from scipy.spatial.transform import Rotation

    rotation = Rotation.from_euler("xz", [30.0, 20.0], degrees=True).as_matrix()
    half = np.asarray(SLAB_SIZE) / 2
    rounding = SLAB_SIZE[2] / 4

    def sdf(points: np.ndarray) -> np.ndarray:
        q = np.abs(points @ rotation) - (half - rounding)  # rotation⁻¹ applied to row vectors
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        return outside + np.minimum(q.max(-1), 0.0) - rounding

    corners = np.stack(np.meshgrid(*[[-h, h] for h in half], indexing="ij"), axis=-1).reshape(-1, 3) @ rotation.T
    return _marching_cubes(sdf, corners.min(0), corners.max(0))


def bunny_fine() -> SurfaceMesh:
    """The pymeshlab bunny in the generator's frame, its edges split (midpoint subdivision, the same surface) until
    none is longer than :data:`FINE_EDGE`."""
    import pymeshlab

    bunny = _unit_frame(SurfaceMesh.load("sample:bunny"))
    meshes = pymeshlab.MeshSet()
    meshes.add_mesh(pymeshlab.Mesh(bunny.vertices, bunny.faces))
    meshes.meshing_surface_subdivision_midpoint(iterations=8, threshold=pymeshlab.PureValue(FINE_EDGE))
    refined = meshes.current_mesh()
    return SurfaceMesh(refined.vertex_matrix(), refined.face_matrix().astype(np.int64))


SHAPES = {
    "tube": Shape(tube),
    "cup": Shape(cup),
    "slab": Shape(slab),
    "bunny-fine": Shape(bunny_fine, texture_frequency=2.5),
}


def get_shape(name: str) -> Shape:
    """The shape called ``name`` (:class:`NerfEditError` naming it and the known ones otherwise)."""
    if name not in SHAPES:
        raise NerfEditError(f"{PREFIX}{name}: unknown shape (available: {', '.join(SHAPES)})")
    return SHAPES[name]


def load_scene_mesh(mesh: str) -> tuple[SurfaceMesh, float]:
    """``shape:NAME`` → the shape's mesh and texture frequency; anything else (a file, ``sample:NAME``) →
    :meth:`SurfaceMesh.load` and frequency 1."""
    text = str(mesh)
    if text.startswith(PREFIX):
        shape = get_shape(text[len(PREFIX) :])
        return shape.build(), shape.texture_frequency
    return SurfaceMesh.load(mesh), 1.0
