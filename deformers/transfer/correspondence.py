"""Triangle correspondence between a source and a target mesh (Sumner & Popović 2004, §5).

Same connectivity: triangle f ↔ triangle f. Otherwise the source is deformed onto the target, in unit coordinates
(``nerfedit_plugin.geometry.mesh.unit_frame`` of each mesh), minimising over its vertices and fourth vertices

    w_S Σ_{adjacent i,j} ‖T_i − T_j‖²_F + w_I Σ_i ‖T_i − I‖²_F + w_C Σ_v ‖x_v − c_v‖²

with the marker vertices held at their target vertices (hard constraints) and ``c_v`` the closest valid target point
of vertex v (closest point on the surface if the normals there agree within 90°, else the nearest target vertex
whose normal does; none: no term). ``w_C`` follows a ramp (default 0, 1, 17, 290, 5000): each phase is one sparse
solve with the closest points of the previous one. Then each fitted source triangle is paired with the closest
(by centroid) target triangle whose normal agrees, within ``max_distance``, and each target triangle with the
closest such source triangle; the pairs are the union.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from deformers.transfer.gradients import (
    gradient_operator,
    gradient_rows,
    to_unit,
    unit_frame,
    with_fourth_vertices,
)
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.cholesky import SparseCholesky
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.normals import face_normals
from nerfedit_plugin.io.atomic import atomic_path

CANDIDATES = 16
"""Nearest candidates (vertices or triangle centroids) searched for one with a compatible normal."""
CACHE_SIZE = 8
"""Correspondences kept in memory (keyed by both meshes, the markers and the parameters)."""


class Correspondence(NamedTuple):
    """``pairs (K, 2)`` int64 (source triangle, target triangle), sorted; ``fitted (V_s, 3)`` the source deformed
    onto the target (target coordinates; the source rest for the identity correspondence); ``distances``: mean
    distance of the fitted source vertices to the target surface after each phase, in target bbox diagonals."""

    pairs: np.ndarray
    fitted: np.ndarray
    distances: tuple[float, ...] = ()


_cache: dict[str, Correspondence] = {}


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V,3) area-weighted sums of the face normals around each vertex (not normalised)."""
    normals = np.zeros_like(vertices)
    face = face_normals(vertices, faces)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face)
    return normals


def _nearest_compatible(points, normals, data, data_normals, upper=np.inf) -> tuple[np.ndarray, np.ndarray]:
    """For each query point: the index of the nearest of the :data:`CANDIDATES` nearest ``data`` points (within
    ``upper``) whose normal has a positive dot product with the query's → ``(indices, found mask)``."""
    _, near = cKDTree(data).query(points, k=min(CANDIDATES, len(data)), distance_upper_bound=upper)
    near = near.reshape(len(points), -1)
    inside = near < len(data)
    safe = np.where(inside, near, 0)
    compatible = inside & (np.einsum("pkd,pd->pk", data_normals[safe], normals) > 0)
    first = compatible.argmax(1)
    return safe[np.arange(len(points)), first], compatible.any(1)


def closest_valid_points(
    points, normals, scene, target: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Closest valid target points ``(P,3)`` of ``points`` with ``normals`` and the mask of points that have one:
    the closest surface point (Open3D ``scene`` of ``target``/``faces``) when its triangle's normal agrees, else the
    nearest target vertex whose normal agrees."""
    triangle, bary = raycast.closest_points(scene, points)
    found = np.einsum("pkd,pk->pd", target[faces[triangle]], bary)
    valid = np.einsum("pd,pd->p", face_normals(target, faces)[triangle], normals) > 0
    rest = np.flatnonzero(~valid)
    if rest.size:
        vertex, ok = _nearest_compatible(points[rest], normals[rest], target, vertex_normals(target, faces))
        found[rest[ok]], valid[rest[ok]] = target[vertex[ok]], True
    return found, valid


def _adjacent(faces: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(P,2) pairs of triangles with a gradient that share an edge."""
    f = np.flatnonzero(ok)
    edges = np.sort(np.concatenate([faces[f][:, [0, 1]], faces[f][:, [1, 2]], faces[f][:, [2, 0]]]), axis=1)
    owner = np.tile(f, 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    return np.column_stack([owner[:-1][same], owner[1:][same]])


def fit_source(
    source: SurfaceMesh,
    target: SurfaceMesh,
    markers: np.ndarray,
    smoothness: float = 1.0,
    identity: float = 0.001,
    closest: tuple[float, ...] = (0.0, 1.0, 17.0, 290.0, 5000.0),
    label: str = "markers",
) -> tuple[np.ndarray, tuple[float, ...]]:
    """Deform ``source`` onto ``target`` (module docstring) with ``markers (M, 2)`` (source vertex, target vertex)
    → ``(fitted (V_s,3) in target unit coordinates, mean distance to the target after each phase)``."""
    src, tgt = (
        to_unit(source.vertices, unit_frame(source.vertices)),
        to_unit(target.vertices, unit_frame(target.vertices)),
    )
    n, faces = len(src), source.faces
    op, ok = gradient_operator(src, faces)
    _require_markers(source, ok, markers, label)
    keep = np.concatenate([np.arange(n), n + np.flatnonzero(ok)])  # columns: vertices, fourth vertices with a gradient
    op = op[:, keep].tocsr()
    adjacent = _adjacent(faces, ok)
    smooth = op[gradient_rows(adjacent[:, 0])] - op[gradient_rows(adjacent[:, 1])]
    ident = op[gradient_rows(np.flatnonzero(ok))]
    base = (smoothness * (smooth.T @ smooth) + identity * (ident.T @ ident)).tocsr()
    base_rhs = identity * (ident.T @ np.tile(np.eye(3), (np.count_nonzero(ok), 1)))
    fixed = np.zeros(len(keep), dtype=bool)
    fixed[markers[:, 0]] = True
    free = np.flatnonzero(~fixed)
    x = with_fourth_vertices(src, faces)[keep]
    x[markers[:, 0]] = tgt[markers[:, 1]]
    scene = raycast.raycasting_scene(tgt, target.faces)
    distances = []
    for weight in closest:
        matrix, rhs = base, base_rhs
        if weight > 0:
            points, valid = closest_valid_points(x[:n], vertex_normals(x[:n], faces), scene, tgt, target.faces)
            pull = np.zeros(len(keep))
            pull[:n] = weight * valid
            matrix = (base + sp.diags(pull)).tocsr()
            rhs = base_rhs.copy()
            rhs[:n] += pull[:n, None] * points
        rows = matrix[free]
        x[free] = SparseCholesky(rows[:, free]).solve(rhs[free] - rows[:, np.flatnonzero(fixed)] @ x[fixed])
        distances.append(float(raycast.distance(scene, x[:n]).mean()))
    return x[:n], tuple(distances)


def _require_markers(source: SurfaceMesh, ok: np.ndarray, markers: np.ndarray, label: str) -> None:
    """Each connected part of the source needs a marker (else its position is undetermined)."""
    n, faces = source.n_vertices, source.faces[ok]
    graph = sp.coo_matrix((np.ones(2 * len(faces)), (faces[:, [0, 1]].ravel(), faces[:, [1, 2]].ravel())), (n, n))
    _, part = connected_components(graph, directed=False)
    used = np.zeros(n, dtype=bool)
    used[faces.ravel()] = True
    loose = np.setdiff1d(np.unique(part[used]), part[markers[:, 0]])
    if loose.size:
        members = np.flatnonzero(used & (part == loose[0]))
        where = np.round(source.vertices[members].mean(0), 4).tolist()
        raise NerfEditError(
            f"{label}: source and target connectivity differ, so the correspondence needs markers; "
            f"{loose.size} connected part(s) of source_rest have none (e.g. {members.size} vertices around {where}, "
            f"vertex {int(members[0])})"
        )


def match_triangles(fitted, source_faces, target, target_faces, max_distance: float) -> np.ndarray:
    """Fitted source and target vertices (same coordinates) → sorted unique ``(K, 2)`` pairs: each triangle of one
    mesh with the closest compatible triangle of the other (centroids within ``max_distance``, normals within 90°)."""
    cs, ct = fitted[source_faces].mean(1), target[target_faces].mean(1)
    ns, nt = face_normals(fitted, source_faces), face_normals(target, target_faces)
    t_of_s, s_found = _nearest_compatible(cs, ns, ct, nt, max_distance)
    s_of_t, t_found = _nearest_compatible(ct, nt, cs, ns, max_distance)
    pairs = np.concatenate(
        [
            np.column_stack([np.flatnonzero(s_found), t_of_s[s_found]]),
            np.column_stack([s_of_t[t_found], np.flatnonzero(t_found)]),
        ]
    )
    return np.unique(pairs.astype(np.int64), axis=0)


def correspondence(
    source: SurfaceMesh,
    target: SurfaceMesh,
    markers: np.ndarray,
    smoothness: float = 1.0,
    identity: float = 0.001,
    closest: tuple[float, ...] = (0.0, 1.0, 17.0, 290.0, 5000.0),
    max_distance: float = 0.05,
    label: str = "markers",
) -> Correspondence:
    """The triangle correspondence (module docstring): identity for the same faces without ``markers``, else fitted
    and matched; ``max_distance`` in target bbox diagonals. Cached in memory by content."""
    if not len(markers) and np.array_equal(source.faces, target.faces):
        f = np.arange(len(target.faces))
        return Correspondence(np.column_stack([f, f]), source.vertices.copy())
    digest = hashlib.sha1(repr((smoothness, identity, tuple(closest), max_distance)).encode())
    for array in (source.vertices, source.faces, target.vertices, target.faces, markers):
        digest.update(np.ascontiguousarray(array).tobytes())
    key = digest.hexdigest()
    if key not in _cache:
        fitted, distances = fit_source(source, target, markers, smoothness, identity, closest, label)
        tgt = to_unit(target.vertices, unit_frame(target.vertices))
        pairs = match_triangles(fitted, source.faces, tgt, target.faces, max_distance)
        centre, size = unit_frame(target.vertices)
        while len(_cache) >= CACHE_SIZE:
            _cache.pop(next(iter(_cache)))
        _cache[key] = Correspondence(pairs, centre + size * fitted, distances)
    found = _cache[key]
    return Correspondence(found.pairs.copy(), found.fitted.copy(), found.distances)


def _faces_digest(faces: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(faces, dtype=np.int64).tobytes()).hexdigest()


def save_correspondence(path: str | Path, corr: Correspondence, source: SurfaceMesh, target: SurfaceMesh) -> Path:
    """Write ``corr`` (with digests of both meshes' faces) atomically to an ``.npz`` file that
    :func:`load_correspondence` reads back (the spec key ``"correspondence"``)."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        np.savez(
            stream,
            pairs=corr.pairs,
            fitted=corr.fitted,
            distances=np.asarray(corr.distances, dtype=np.float64),
            source_faces=_faces_digest(source.faces),
            target_faces=_faces_digest(target.faces),
        )
    return path


def load_correspondence(path: Path, source: SurfaceMesh, target: SurfaceMesh, label: str) -> Correspondence:
    """Read a file of :func:`save_correspondence`; it must have been computed for these meshes' faces (``label``,
    the spec and key, starts every error)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = {key: data[key] for key in ("pairs", "fitted", "distances", "source_faces", "target_faces")}
    except (OSError, ValueError, KeyError) as exc:
        raise NerfEditError(f"{label}: {path}: not a saved correspondence ({exc})") from None
    for key, mesh, name in (("source_faces", source, "source_rest"), ("target_faces", target, "the rest mesh")):
        if str(stored[key]) != _faces_digest(mesh.faces):
            raise NerfEditError(f"{label}: {path}: was computed for other faces than those of {name}")
    pairs = stored["pairs"].astype(np.int64)
    if (
        pairs.ndim != 2
        or pairs.shape[1] != 2
        or stored["fitted"].shape != (source.n_vertices, 3)
        or (pairs.size and (pairs.min() < 0 or pairs[:, 0].max() >= len(source.faces)))
        or (pairs.size and pairs[:, 1].max() >= len(target.faces))
    ):
        raise NerfEditError(f"{label}: {path}: pairs {pairs.shape} or fitted {stored['fitted'].shape} malformed")
    return Correspondence(pairs, stored["fitted"].astype(np.float64), tuple(stored["distances"].tolist()))
