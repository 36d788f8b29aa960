"""Deformation gradients of triangle meshes and the transfer system (Sumner & Popović 2004, §3–5).

A triangle (v1, v2, v3) gets a fourth vertex ``v4 = v1 + n / √‖n‖`` (``n = (v2 − v1) × (v3 − v1)``), so that a
deformed copy has a 3×3 gradient ``T = Ṽ V⁻¹`` with ``V = [v2 − v1, v3 − v1, v4 − v1]``. Stacking the vertices and
the fourth vertices into ``X ((V + F), 3)``, ``Tᵀ`` is linear in ``X``: rows ``3f .. 3f+2`` of
:func:`gradient_operator` ``@ X`` hold ``T_fᵀ``.

:class:`TransferSystem` minimises ``Σ_k ‖S_{s_k} − T_{t_k}(X)‖²_F`` over the target's ``X`` for the triangle pairs
``(s_k, t_k)`` of a correspondence, ``S`` the source pose's gradients. The normal matrix depends on the target rest
mesh and the pairs only: the fourth vertices are eliminated exactly (each appears in the pairs of its own triangle
only, so its block is diagonal), one vertex per connected part is pinned (the energy ignores translations), the
reduced matrix is factored once, and each pose is one sparse product plus one back-substitution. The free
translation of each part is then set so that its paired triangle centroids move, on average, as the source's do.
All of it runs in unit coordinates (``nerfedit_plugin.geometry.mesh.unit_frame``): scale and position of the meshes
do not matter.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.cholesky import SparseCholesky
from nerfedit_plugin.geometry.mesh import SurfaceMesh, unit_frame
from nerfedit_plugin.geometry.normals import face_normals

DEGENERATE = 1e-12
"""A triangle whose doubled area is at most this (in unit coordinates, bbox diagonal 1) has no gradient."""

#: ``[v1 v2 v3 v4] @ CORNERS = [v2 − v1, v3 − v1, v4 − v1]``
CORNERS = np.array([[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def to_unit(vertices: np.ndarray, frame: tuple[np.ndarray, float]) -> np.ndarray:
    """``vertices (..., 3)`` in the unit coordinates of ``frame`` (``nerfedit_plugin.geometry.mesh.unit_frame``)."""
    return (vertices - frame[0]) / frame[1]


def with_fourth_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """vertices (V,3), faces (F,3) → ``X ((V + F), 3)``: the vertices, then each triangle's ``v4 = v1 + n/√‖n‖``
    (``v1`` for a triangle of zero area)."""
    v1 = vertices[faces[:, 0]]
    normal = face_normals(vertices, faces)
    root = np.sqrt(np.linalg.norm(normal, axis=1))
    return np.concatenate([vertices, v1 + normal / np.maximum(root, 1e-300)[:, None]])


def gradient_operator(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Rest vertices (V,3) in unit coordinates, faces (F,3) → ``(G, ok)``: ``G (3F × (V + F))`` with
    ``(G @ X)[3f + a] = column a of T_f`` for the stacked positions ``X`` of :func:`with_fourth_vertices`, and
    ``ok (F,)`` the triangles with a gradient (doubled area > :data:`DEGENERATE`; the others' rows are zero)."""
    n, f = len(vertices), len(faces)
    ok = np.linalg.norm(face_normals(vertices, faces), axis=1) > DEGENERATE
    x = with_fourth_vertices(vertices, faces)
    corners = np.column_stack([faces, n + np.arange(f)])  # (F,4) rows of X
    edges = np.einsum("fkd,ke->fde", x[corners[ok]], CORNERS)  # V (columns: edges)
    local = np.zeros((f, 4, 3))
    local[ok] = CORNERS @ np.linalg.inv(edges)  # T = [v1..v4] CORNERS V⁻¹
    rows = (3 * np.arange(f)[:, None, None] + np.arange(3)[None, None, :]).repeat(4, axis=1)  # (F,4,3)
    columns = np.broadcast_to(corners[:, :, None], (f, 4, 3))
    op = sp.csr_matrix((local.ravel(), (rows.ravel(), columns.ravel())), shape=(3 * f, n + f))
    return op, ok


def gradient_rows(triangles: np.ndarray) -> np.ndarray:
    """Triangle indices (K,) → the rows ``(3K,)`` of their gradients in :func:`gradient_operator`."""
    return (3 * np.asarray(triangles)[:, None] + np.arange(3)).ravel()


class TransferSystem:
    """Prefactored deformation transfer from ``source`` (rest) onto ``target`` (rest) for triangle ``pairs (K, 2)``
    (source triangle, target triangle); :meth:`transfer` maps one source pose ``(V_s, 3)`` to target vertices."""

    def __init__(self, source: SurfaceMesh, target: SurfaceMesh, pairs: np.ndarray) -> None:
        self.source_frame, self.target_frame = unit_frame(source.vertices), unit_frame(target.vertices)
        self.source_faces = source.faces
        src_op, src_ok = gradient_operator(to_unit(source.vertices, self.source_frame), source.faces)
        tgt_rest = to_unit(target.vertices, self.target_frame)
        tgt_op, tgt_ok = gradient_operator(tgt_rest, target.faces)
        pairs = pairs[src_ok[pairs[:, 0]] & tgt_ok[pairs[:, 1]]]
        n, used = target.n_vertices, np.unique(pairs[:, 1])
        system = tgt_op[gradient_rows(pairs[:, 1])]  # A: X ↦ the paired target gradients
        fourth = system[:, n + used].tocsc()
        corner = system[:, :n].tocsc()
        inverse_diagonal = sp.diags(1.0 / np.asarray(fourth.power(2).sum(0)).ravel())  # (A₄ᵀA₄)⁻¹, diagonal
        coupling = (corner.T @ fourth).tocsr()  # A_vᵀA₄
        reduce = (corner.T - coupling @ inverse_diagonal @ fourth.T).tocsr()  # A_vᵀ − A_vᵀA₄ (A₄ᵀA₄)⁻¹ A₄ᵀ
        matrix = (reduce @ corner).tocsr()  # Schur complement of the fourth vertices in AᵀA
        self._rhs = (reduce @ src_op[gradient_rows(pairs[:, 0])]).tocsr()  # stacked source pose ↦ reduced rhs

        referenced = np.zeros(n, dtype=bool)
        referenced[target.faces[used].ravel()] = True
        edges = np.concatenate([target.faces[used][:, [0, 1]], target.faces[used][:, [1, 2]]])
        graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
        n_parts, part = connected_components(graph, directed=False)
        touched = np.flatnonzero(referenced)
        pinned = ~referenced  # vertices of no paired triangle stay at rest
        pinned[touched[np.unique(part[touched], return_index=True)[1]]] = True  # the gauge: one vertex per part
        self._free, self._pinned = np.flatnonzero(~pinned), np.flatnonzero(pinned)
        self._rest = tgt_rest
        self._factor = SparseCholesky(matrix[self._free][:, self._free])
        self._coupling = matrix[self._free][:, self._pinned].tocsr()

        # translation of part p: mean over its pairs of (target rest + source displacement − target) centroids
        k = len(pairs)
        centroid_t = _centroids(target.faces[pairs[:, 1]], n)
        centroid_s = _centroids(source.faces[pairs[:, 0]], source.n_vertices)
        pair_part = part[target.faces[pairs[:, 1], 0]]
        counts = np.bincount(pair_part, minlength=n_parts)
        mean = sp.csr_matrix((1.0 / counts[pair_part], (pair_part, np.arange(k))), shape=(n_parts, k))
        self._mean_target = (mean @ centroid_t).tocsr()
        self._mean_source = (mean @ centroid_s).tocsr()
        src_rest = to_unit(source.vertices, self.source_frame)
        self._offset = self._mean_target @ tgt_rest - self._mean_source @ src_rest
        self._part = np.where(referenced, part, -1)

    def transfer(self, pose: np.ndarray) -> np.ndarray:
        """Source pose vertices (V_s,3) → the target's vertices (V_t,3) float64 under the transferred gradients."""
        pose = to_unit(np.asarray(pose, dtype=np.float64), self.source_frame)
        rhs = self._rhs @ with_fourth_vertices(pose, self.source_faces)
        x = self._rest.copy()
        x[self._free] = self._factor.solve(rhs[self._free] - self._coupling @ x[self._pinned])
        shift = self._offset + self._mean_source @ pose - self._mean_target @ x
        moved = self._part >= 0
        x[moved] += shift[self._part[moved]]
        return self.target_frame[0] + self.target_frame[1] * x


def _centroids(faces: np.ndarray, n: int) -> sp.csr_matrix:
    """(K × n) sparse: row k averages the three vertices of ``faces[k]``."""
    k = len(faces)
    return sp.csr_matrix((np.full(3 * k, 1.0 / 3.0), (np.repeat(np.arange(k), 3), faces.ravel())), shape=(k, n))


def check_determined(source: SurfaceMesh, target: SurfaceMesh, pairs: np.ndarray, label: str) -> None:
    """Every target triangle with a gradient must be paired with a source triangle with one; else a NerfEditError
    (``label`` first) saying how many are not and where (the bounding box of their centroids)."""
    _, ok = gradient_operator(to_unit(target.vertices, unit_frame(target.vertices)), target.faces)
    _, source_ok = gradient_operator(to_unit(source.vertices, unit_frame(source.vertices)), source.faces)
    matched = np.zeros(len(target.faces), dtype=bool)
    matched[pairs[source_ok[pairs[:, 0]], 1]] = True
    missing = np.flatnonzero(ok & ~matched)
    if missing.size:
        centres = target.vertices[target.faces[missing]].mean(1)
        lo, hi = np.round(centres.min(0), 4).tolist(), np.round(centres.max(0), 4).tolist()
        raise NerfEditError(
            f"{label}: the correspondence leaves {missing.size} of {len(target.faces)} target triangles unmatched "
            f"(e.g. triangle {int(missing[0])}; centroids within {lo} .. {hi}): add markers there or raise "
            "match_distance"
        )
