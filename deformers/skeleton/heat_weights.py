"""Automatic skinning weights by bone heat (Baran & Popović, "Automatic Rigging and Animation of 3D Characters",
SIGGRAPH 2007).

``bone_heat_weights(vertices (V,3), faces (F,3), heads (J,3), tails (J,3)) → (V,J) float64`` with rows summing to 1:
for every bone ``j``, ``(K + M H) w_j = M H p_j`` (``K = −L`` the cotangent stiffness, ``M`` the lumped mass, ``H_ii =
k_i c / d_i²``, ``p_j`` the bones heating each vertex), one factorisation for all bones; with ``visibility`` only bones
a vertex can see heat it (Open3D ray tests). Details: docs/method.md, "Skeleton: bone-heat weights".
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.cotangent import cotangent_weights, edge_laplacian
from nerfedit_plugin.geometry.normals import face_normals
from nerfedit_plugin.timing import Progress, no_progress

#: relative distance within which bones count as equidistant from a vertex
TIE_TOLERANCE = 1e-6
#: distances are clamped to this fraction of the bounding-box diagonal (a vertex on a bone)
MIN_DISTANCE = 1e-4


def cotangent_stiffness(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """vertices (V,3) float64, faces (F,3) int64 → ``K (V,V)`` float64 CSR, ``K = −L``: ``K_ij = −½ Σ cot(opposite
    angles)`` off the diagonal, rows summing to 0 (PSD); no stored zeros.

    Assembled from the core's per-triangle cotangent weights (0 on degenerate triangles).
    """
    stiffness = edge_laplacian(faces, cotangent_weights(vertices, faces), len(vertices))
    stiffness.eliminate_zeros()
    return stiffness


def lumped_mass(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """vertices (V,3) float64, faces (F,3) int64 → ``(V,)`` float64 barycentric lumped mass: a third of the area of
    every incident triangle."""
    area = 0.5 * np.linalg.norm(face_normals(vertices, faces), axis=1)
    return np.bincount(faces.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(vertices))


def closest_on_segments(points: np.ndarray, heads: np.ndarray, tails: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """points (N,3), heads (J,3), tails (J,3) float64 → closest points ``(N,J,3)`` on each segment head → tail and
    their distances ``(N,J)``, float64."""
    axis = tails - heads
    length2 = np.sum(axis * axis, axis=1)
    rel = points[:, None, :] - heads[None]
    s = np.divide(
        np.einsum("njk,jk->nj", rel, axis), length2, out=np.zeros((len(points), len(heads))), where=length2 > 0
    )
    closest = heads[None] + np.clip(s, 0.0, 1.0)[..., None] * axis[None]
    return closest, np.linalg.norm(points[:, None, :] - closest, axis=2)


def occluded(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """vertices (V,3), faces (F,3), origins (N,3), targets (N,3) → ``(N,)`` bool: whether the segment
    ``origin → target`` crosses the mesh, ignoring a short stretch at both ends (Open3D, float32)."""
    gap = 1e-4 * float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    delta = targets - origins
    length = np.linalg.norm(delta, axis=1, keepdims=True)
    unit = np.divide(delta, length, out=np.zeros_like(delta), where=length > 0)
    start, end = origins + gap * unit, targets - gap * unit
    short = length[:, 0] <= 2 * gap
    rays = np.concatenate([start, end - start], axis=1).astype(np.float32)
    hit = raycast.occluded(raycast.raycasting_scene(vertices, faces), rays, tnear=0.0, tfar=1.0)
    return hit & ~short


def heat_sources(dist: np.ndarray, allowed: np.ndarray, nearest: int) -> tuple[np.ndarray, np.ndarray]:
    """dist (V,J) float64, allowed (V,J) bool, nearest int → per vertex, ``p (V,J)`` float64 (1/k on each of its k
    heating bones) and the distance ``(V,)`` float64 to the nearest of them.

    Only ``allowed`` bones may heat; a vertex with none gets a zero row and distance ``inf``.
    """
    masked = np.where(allowed, dist, np.inf)
    kth = np.sort(masked, axis=1)[:, min(nearest, dist.shape[1]) - 1 : min(nearest, dist.shape[1])]
    heating = allowed & (masked <= kth * (1.0 + TIE_TOLERANCE))
    counts = heating.sum(1, keepdims=True)
    p = np.divide(heating, counts, out=np.zeros(dist.shape), where=counts > 0)
    return p, masked.min(1)


def bone_heat_weights(
    vertices: np.ndarray,
    faces: np.ndarray,
    heads: np.ndarray,
    tails: np.ndarray,
    *,
    nearest: int = 1,
    visibility: bool = True,
    strength: float = 1.0,
    progress: Progress = no_progress,
) -> np.ndarray:
    """vertices (V,3) float, faces (F,3) int, heads (J,3) float, tails (J,3) float → skinning weights ``(V,J)``
    float64 of the bones ``heads[j] → tails[j]`` on the triangle mesh, in [0, 1], rows summing to 1. ``progress``
    is told each step (visibility, factorisation, solve)."""
    from cholespy import CholeskySolverD, MatrixType

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    heads, tails = np.asarray(heads, dtype=np.float64), np.asarray(tails, dtype=np.float64)
    n = len(vertices)
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))

    closest, dist = closest_on_segments(vertices, heads, tails)
    allowed = np.ones(dist.shape, dtype=bool)
    if visibility and len(faces):
        progress(0, None, "bone-heat weights: visibility")
        origins = np.repeat(vertices, len(heads), axis=0)
        allowed = ~occluded(vertices, faces, origins, closest.reshape(-1, 3)).reshape(dist.shape)
    p, d = heat_sources(dist, allowed, nearest)

    stiffness = cotangent_stiffness(vertices, faces)
    _, component = connected_components(stiffness, directed=False)
    blind = ~np.isin(component, component[np.isfinite(d)])  # components no bone can see: plain nearest bones
    if blind.any():
        p[blind], d[blind] = heat_sources(dist[blind], np.ones_like(allowed[blind]), nearest)

    mass = lumped_mass(vertices, faces)
    mass[mass <= 0] = mass[mass > 0].mean() if (mass > 0).any() else 1.0  # vertices in no (non-degenerate) face
    counts = np.count_nonzero(p, axis=1)
    heat = np.zeros(n)
    seen = np.isfinite(d)
    heat[seen] = counts[seen] * strength / np.maximum(d[seen], MIN_DISTANCE * diag) ** 2
    system = (stiffness + sp.diags(mass * heat)).tocoo()
    progress(0, None, "bone-heat weights: factorising")
    solver = CholeskySolverD(
        n, system.row.astype(np.int32), system.col.astype(np.int32), np.ascontiguousarray(system.data), MatrixType.COO
    )
    rhs = np.ascontiguousarray((mass * heat)[:, None] * p)
    weights = np.zeros_like(rhs)
    progress(0, None, f"bone-heat weights: solving for {len(heads)} bones")
    solver.solve(rhs, weights)
    weights = np.clip(weights, 0.0, None)
    return weights / weights.sum(1, keepdims=True)
