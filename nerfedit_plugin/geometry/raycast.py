"""Open3D ``RaycastingScene`` of a triangle mesh and the queries the package runs on it (float32, CPU)."""

from __future__ import annotations

import numpy as np


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    """vertices (V,3) float, faces (F,3) int → ``open3d.t.geometry.RaycastingScene`` holding the triangles.

    Open3D works in float32: vertices are cast to float32, faces to uint32."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
    )
    return scene


def _float32(array: np.ndarray):
    """points (M,3) or rays (N,6) float → the Open3D float32 tensor of a query."""
    import open3d as o3d

    return o3d.core.Tensor(np.ascontiguousarray(array, dtype=np.float32))


def distance(scene, points: np.ndarray) -> np.ndarray:
    """scene, points (M,3) float → (M,) float32 unsigned distance to the nearest triangle."""
    return scene.compute_distance(_float32(points)).numpy()


def signed_distance(scene, points: np.ndarray) -> np.ndarray:
    """scene (watertight triangles), points (M,3) float → (M,) float32 distance to the nearest triangle, negative
    inside."""
    return scene.compute_signed_distance(_float32(points)).numpy()


def occupancy(scene, points: np.ndarray, nsamples: int = 1) -> np.ndarray:
    """scene (watertight triangles), points (M,3) float → (M,) bool inside, by ray parity (majority of
    ``nsamples`` rays)."""
    return scene.compute_occupancy(_float32(points), nsamples=nsamples).numpy() > 0.5


def closest_points(scene, points: np.ndarray, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """scene, points (M,3) float → closest triangle (M,) int64 and the barycentrics (M,3) ``dtype`` of the closest
    point in it (from Open3D's float32 uv: ``(1 − u − v, u, v)``, computed in ``dtype``)."""
    hit = scene.compute_closest_points(_float32(points))
    uv = hit["primitive_uvs"].numpy().astype(dtype)
    return hit["primitive_ids"].numpy().astype(np.int64), np.column_stack([1.0 - uv.sum(1), uv])


def cast_rays(scene, rays: np.ndarray) -> dict[str, np.ndarray]:
    """scene, rays (..., 6) float (origin, direction) → Open3D's first hits as numpy arrays (``t_hit`` (...,)
    float32, ``inf`` on a miss; ``primitive_ids`` (...,) uint32; ``primitive_uvs`` (..., 2); ``primitive_normals``
    (..., 3); ``geometry_ids``)."""
    return {k: v.numpy() for k, v in scene.cast_rays(_float32(rays)).items()}


def occluded(scene, rays: np.ndarray, tnear: float = 0.0, tfar: float = float("inf")) -> np.ndarray:
    """scene, rays (N,6) float (origin, direction) → (N,) bool: a triangle lies at ``tnear < t < tfar`` (``t`` in
    units of the direction's length)."""
    return scene.test_occlusions(_float32(rays), tnear=tnear, tfar=tfar).numpy()
