"""Watertight wraps of triangle soups: pymeshlab alpha wrap, then quadric decimation (offset cages, tet proxies)."""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.geometry.mesh import SurfaceMesh, unit_frame
from nerfedit_plugin.timing import Stopwatch


def wrap_and_decimate(
    vertices: np.ndarray,
    faces: np.ndarray,
    alpha: float,
    offset: float,
    *,
    percent: bool = False,
    max_faces: int | None = None,
    max_vertices: int | None = None,
    preserve_normal: bool = False,
    clock: Stopwatch | None = None,
) -> SurfaceMesh:
    """vertices (V,3) float64, faces (F,3) int → the alpha wrap (watertight, no self-intersections), decimated.

    pymeshlab's ``generate_alpha_wrap`` with ball size ``alpha`` at distance ``offset`` outside the input (absolute,
    or with ``percent`` in percent of the bounding-box diagonal); then, when the wrap has more than ``max_faces``
    faces, quadric edge collapse (topology kept, normals too with ``preserve_normal``) down to ``max_faces``, or when
    it has more than ``max_vertices`` vertices, down to ``2 · max_vertices − 4`` faces (a closed genus-0 mesh with
    that many vertices). ``clock`` times the stages ``wrap`` and ``decimate``. Both run on the input moved to its
    bounding-box centre and scaled to a unit diagonal (and the result is mapped back), so the wrap of a scaled or
    moved input is the scaled or moved wrap: MeshLab's meshes are float32 and its tolerances absolute.
    """
    import pymeshlab

    clock = clock or Stopwatch()
    vertices = np.asarray(vertices, dtype=np.float64)
    centre, size = unit_frame(vertices)
    if not percent:
        alpha, offset = alpha / size, offset / size
    meshset = pymeshlab.MeshSet()
    meshset.add_mesh(pymeshlab.Mesh((vertices - centre) / size, faces.astype(np.int32)))
    with clock.stage("wrap"):
        value = pymeshlab.PercentageValue if percent else pymeshlab.PureValue
        meshset.generate_alpha_wrap(alpha=value(alpha), offset=value(offset))
    with clock.stage("decimate"):
        wrapped = meshset.current_mesh()
        if max_faces is not None and wrapped.face_number() > max_faces:
            target = max_faces
        elif max_vertices is not None and wrapped.vertex_number() > max_vertices:
            target = 2 * max_vertices - 4
        else:
            target = None
        if target is not None:
            meshset.meshing_decimation_quadric_edge_collapse(
                targetfacenum=target, preservetopology=True, preservenormal=preserve_normal
            )
    wrapped = meshset.current_mesh()
    return SurfaceMesh(wrapped.vertex_matrix() * size + centre, wrapped.face_matrix())
