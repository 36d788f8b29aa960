"""Mesh clean-up for scenes: the floor (the largest plane) and floaters (small connected parts).

A mesh extracted from a scene holds the floor, the objects standing on it (one connected part with the floor) and
floaters (small parts the field left in the air). Connectivity and sub-meshes are :class:`SurfaceMesh` methods
(``component_labels``, ``submesh``); this module finds and drops the floor and drops floaters.
"""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh, unit_frame

PLANE_DISTANCE = 5e-3
"""Default largest distance of a vertex on the plane from it, as a fraction of the bounding-box diagonal."""
RANSAC_ITERATIONS = 1000
RANSAC_SEED = 0


def largest_plane(mesh: SurfaceMesh, distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """→ ``(plane (4,) float64, on (V,) bool)``: the plane ``a x + b y + c z + d = 0`` (unit normal ``(a, b, c)``,
    pointing to the side with more vertices off the plane: up, for a floor) holding the most vertices within
    ``distance`` (mesh units; default :data:`PLANE_DISTANCE` × the bounding-box diagonal), and those vertices.

    RANSAC (Open3D ``segment_plane``, its random generator seeded with :data:`RANSAC_SEED`: the same mesh gives the
    same plane) on the mesh in its unit frame, then a least-squares refit to the inliers, whose vertices within
    ``distance`` are ``on``. Fewer than 3 vertices, or a non-positive ``distance``, is a :class:`NerfEditError`."""
    import open3d as o3d

    if mesh.n_vertices < 3:
        raise NerfEditError(f"largest plane: needs at least 3 vertices, the mesh has {mesh.n_vertices}")
    centre, size = unit_frame(mesh.vertices)
    distance = PLANE_DISTANCE * mesh.bbox_diagonal if distance is None else float(distance)
    if not distance > 0:
        raise NerfEditError(f"largest plane: distance must be > 0, got {distance}")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector((mesh.vertices - centre) / size))
    o3d.utility.random.seed(RANSAC_SEED)
    _, inliers = cloud.segment_plane(distance / size, 3, RANSAC_ITERATIONS)
    fitted = mesh.vertices[inliers]
    mean = fitted.mean(axis=0)
    normal = np.linalg.svd(fitted - mean, full_matrices=False)[2][2]
    height = (mesh.vertices - mean) @ normal
    on = np.abs(height) <= distance
    if np.count_nonzero(height[~on] < 0) > np.count_nonzero(height[~on] > 0):
        normal = -normal
    return np.append(normal, -normal @ mean), on


def drop_floaters(mesh: SurfaceMesh, min_fraction: float) -> SurfaceMesh:
    """→ ``mesh`` without its connected parts (:meth:`SurfaceMesh.component_labels`) of fewer faces than
    ``min_fraction`` × the largest part's, their vertices dropped; kept vertices keep their positions, order and
    colours. ``min_fraction`` in [0, 1] (0 keeps every part, 1 the largest ones), else a :class:`NerfEditError`."""
    if not 0 <= min_fraction <= 1:
        raise NerfEditError(f"drop floaters: the fraction must lie in [0, 1], got {min_fraction}")
    labels = mesh.component_labels()
    faces = np.bincount(labels[mesh.faces[:, 0]], minlength=labels.max() + 1)
    return mesh.submesh(faces[labels] >= min_fraction * faces.max())[0]


def drop_plane(mesh: SurfaceMesh, distance: float | None = None) -> SurfaceMesh:
    """→ ``mesh`` without the vertices on its :func:`largest_plane` (within ``distance``) and those left without a
    face, so objects standing on a floor come apart; kept vertices keep their positions, order and colours."""
    part = mesh.submesh(~largest_plane(mesh, distance)[1])[0]
    used = np.zeros(part.n_vertices, dtype=bool)
    used[part.faces] = True
    return part.submesh(used)[0]
