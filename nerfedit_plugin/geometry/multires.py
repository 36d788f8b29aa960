"""Multiresolution ARAP (Botsch & Sorkine 2008, §5; Kobbelt et al. 1998): solve on a coarse level of the surface,
carry the fine surface as detail in the local frames of the coarse solution.

Coarse level (:func:`coarse_level`): vertex clustering of the fine surface ``P (V,3)`` on a uniform grid
(:func:`~nerfedit_plugin.geometry.mesh.vertex_clusters`; cell chosen for a given vertex count), coarse vertices
``q_k`` the means of their clusters. Binding: each fine vertex ``p_i`` is bound to the closest point of the coarse
surface, barycentrics ``w_ic`` on the corners ``k_ic`` of its triangle (rows summing to 1).

Solve (:class:`MultiresArap`): exact ARAP (:class:`~nerfedit_plugin.geometry.arap.ArapSolver`) on the coarse level
with coarse handles derived from the fine ones, giving ``y_k`` and per-vertex rotations ``R_k``
(:meth:`ArapSolver.vertex_rotations`); the fine surface follows as

    ``p'_i = Σ_c w_ic (y_k + R_k (p_i − q_k))``,  ``k = k_ic``,

each fine vertex its detail ``p_i − q_k`` turned by the rotations of the coarse vertices around it. A common rigid
motion ``x ↦ R x + t`` of every coarse vertex moves every fine vertex by it (the weights sum to 1); a coarse level
equal to the mesh (each ``w_i = (1, 0, 0)`` on its own vertex, ``p_i = q_i``) gives ``p'_i = y_i`` exactly.
Handle vertices of the fine mesh are set to their targets by the caller.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import _multires_kernel as _kernel
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.arap import ArapResult, ArapSolver
from nerfedit_plugin.geometry.launch import launch
from nerfedit_plugin.geometry.mesh import SurfaceMesh, vertex_clusters

CELL_FACTOR = 1.17
"""Cell size of the clustering in units of ``sqrt(area / n)`` for ``n`` coarse vertices (on the subdivided
bunnies this lands within ~10 % of ``n``; one correction step follows)."""


@dataclasses.dataclass(frozen=True)
class CoarseLevel:
    """A coarse level of a fine surface of V vertices and its binding.

    ``coarse`` (C vertices), ``owner (V,) int64`` the cluster (coarse vertex) of each fine vertex, ``corners (V,3)
    int64`` and ``weights (V,3) float64`` the coarse vertices each fine vertex blends and their barycentric weights,
    ``parts (C,) int64`` the connected part of the fine mesh (through its edges) each cluster lies in,
    ``detail (2,) float64`` the mean and max distance of the fine vertices to the coarse surface."""

    coarse: SurfaceMesh
    owner: np.ndarray
    corners: np.ndarray
    weights: np.ndarray
    parts: np.ndarray
    detail: np.ndarray

    @property
    def is_identity(self) -> bool:
        """Whether the coarse level is the fine mesh itself (each fine vertex its own cluster)."""
        return len(self.coarse.vertices) == len(self.owner) and bool(np.all(self.weights[:, 0] == 1.0))

    def arrays(self) -> dict[str, np.ndarray]:
        """The level as named arrays (:meth:`from_arrays` reads them back)."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "coarse"}
        return {**fields, "coarse_vertices": self.coarse.vertices, "coarse_faces": self.coarse.faces}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> CoarseLevel:
        coarse = SurfaceMesh(arrays["coarse_vertices"], arrays["coarse_faces"])
        names = [f.name for f in dataclasses.fields(cls) if f.name != "coarse"]
        return cls(coarse, **{name: np.asarray(arrays[name]) for name in names})


def _parts(n: int, faces: np.ndarray) -> np.ndarray:
    """n nodes, faces (F,3) int64 over them → (n,) int64 connected-part label of each node through the face edges."""
    i = faces.ravel()
    j = np.roll(faces, -1, axis=1).ravel()
    keep = i != j
    graph = sp.csr_matrix((np.ones(int(keep.sum()), dtype=bool), (i[keep], j[keep])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def identity_level(mesh: SurfaceMesh) -> CoarseLevel:
    """The coarse level that is ``mesh`` itself: each vertex bound to itself with weight 1."""
    n = mesh.n_vertices
    corners = np.repeat(np.arange(n)[:, None], 3, axis=1)
    weights = np.zeros((n, 3))
    weights[:, 0] = 1.0
    return CoarseLevel(mesh, np.arange(n), corners, weights, _parts(n, mesh.faces), np.zeros(2))


def coarse_level(mesh: SurfaceMesh, vertices: int) -> CoarseLevel:
    """The vertex clustering of ``mesh`` with about ``vertices`` coarse vertices and its binding (the closest point
    of the coarse surface to each fine vertex); ``vertices`` ≥ the mesh's vertex count gives :func:`identity_level`.
    Duplicate coarse faces (the same three vertices) are kept once."""
    if vertices >= mesh.n_vertices:
        return identity_level(mesh)
    p, f = mesh.vertices, mesh.faces
    area = 0.5 * float(np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1).sum())
    if not area > 0:
        raise NerfEditError("multiresolution: the mesh has no area to cluster")
    cell = CELL_FACTOR * np.sqrt(area / vertices)
    coarse, owner = vertex_clusters(mesh, cell)
    if abs(coarse.n_vertices / vertices - 1) > 0.1:  # one correction: the count grows like cell⁻²
        coarse, owner = vertex_clusters(mesh, cell * np.sqrt(coarse.n_vertices / vertices))
    _, unique = np.unique(np.sort(coarse.faces, axis=1), axis=0, return_index=True)
    coarse = SurfaceMesh(coarse.vertices, coarse.faces[np.sort(unique)])
    if len(coarse.faces) == 0:
        raise NerfEditError(f"multiresolution: the clustering to {vertices} vertices left no triangle")
    triangle, weights = raycast.closest_points(raycast.raycasting_scene(coarse.vertices, coarse.faces), p)
    weights = np.clip(weights, 0.0, None)
    weights /= weights.sum(1, keepdims=True)
    corners = coarse.faces[triangle]
    closest = np.einsum("vc,vcd->vd", weights, coarse.vertices[corners])
    distance = np.linalg.norm(closest - p, axis=1) / mesh.bbox_diagonal
    clusters = _parts(coarse.n_vertices, owner[f])
    return CoarseLevel(coarse, owner, corners, weights, clusters, np.array([distance.mean(), distance.max()]))


def rigid_fit(rest: np.ndarray, moved: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """rest (M,3), moved (M,3) float64 → ``(R (3,3), t (3,), residual)``: the rigid motion ``x ↦ R x + t`` closest to
    ``rest → moved`` in least squares and its largest point residual. Kabsch (SVD of the cross-covariance), then two
    Gauss–Newton steps ``R ← exp([ω]×) R``, ``(Σ |c|² I − c cᵀ) ω = Σ c × b`` (``c = R a``; ``a``, ``b`` centred),
    which stay exact to rounding where the cross-covariance has repeated singular values."""
    a, b = rest - rest.mean(0), moved - moved.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    rotation = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    for _ in range(2):
        c = a @ rotation.T
        normal = np.sum(c * c) * np.eye(3) - c.T @ c
        step = np.linalg.lstsq(normal, np.cross(c, b).sum(0), rcond=1e-12)[0]
        rotation = Rotation.from_rotvec(step).as_matrix() @ rotation
    shift = moved.mean(0) - rotation @ rest.mean(0)
    return rotation, shift, float(np.linalg.norm(rest @ rotation.T + shift - moved, axis=1).max(initial=0.0))


class MultiresArap:
    """ARAP on a :class:`CoarseLevel` of a fine mesh with handle vertices ``handles (H,) int64`` of the fine mesh.

    Coarse handles: a cluster whose members are at least half handle vertices is fixed (as is every cluster holding
    a handle vertex in a part of the fine mesh where no cluster is); its target is the mean of its members' targets
    when all are handles, else the least-squares similarity of its handle members' motion evaluated at the coarse
    vertex (exact for the spec's similarity transforms when the members span a plane). A connected part of the
    coarse surface without a coarse handle that lies in a part of the fine mesh which has one (the clustering cut it
    off) moves rigidly with its nearest solved coarse vertex. A part of the fine mesh without a handle vertex is a
    :class:`NerfEditError`."""

    def __init__(self, level: CoarseLevel, rest: SurfaceMesh, handles: np.ndarray, energy: str | None = None):
        self.level, self.rest, self.handles = level, rest, np.asarray(handles, dtype=np.int64)
        coarse, owner = level.coarse, level.owner
        n = coarse.n_vertices
        if level.is_identity:
            self.fixed, self._partial = self.handles, np.zeros(0, dtype=np.int64)
        else:
            members = np.bincount(owner, minlength=n)
            held = np.bincount(owner[self.handles], minlength=n)
            fixed = (2 * held >= members) & (held > 0)
            anchored_parts = np.zeros(n, dtype=bool)
            anchored_parts[level.parts[fixed]] = True
            fixed |= (held > 0) & ~anchored_parts[level.parts]
            self.fixed = np.flatnonzero(fixed)
            self._partial = self.fixed[held[self.fixed] < members[self.fixed]]
        self._targets_map, self._similarity = self._target_weights()
        self._rest_handles = rest.vertices[self.handles]  # (H,3): what coarse_targets subtracts on every call
        stray = ~rest.referenced()  # vertices of no face
        self._stray = np.flatnonzero(stray)
        handled = np.zeros(n, dtype=bool)
        handled[level.parts[owner[self.handles]]] = True
        loose = ~handled[level.parts[owner]] & ~stray
        if loose.any():
            vertex = int(np.flatnonzero(loose)[0])
            raise NerfEditError(
                f"ARAP: a connected part of the mesh (containing vertex {vertex}) has no fixed vertex (handle), so "
                "its position is undetermined: give every connected part at least one handle"
            )
        labels = _parts(n, coarse.faces)
        anchored = np.zeros(n, dtype=bool)  # by component label
        anchored[labels[self.fixed]] = True
        solved = anchored[labels]
        referenced = np.zeros(n, dtype=bool)
        referenced[coarse.faces.ravel()] = True
        solved &= referenced
        faces = coarse.faces if solved[coarse.faces].all() else coarse.faces[solved[coarse.faces[:, 0]]]
        self.solver = ArapSolver(coarse.vertices, faces, energy=energy, fixed=self.fixed)
        self._carried = np.flatnonzero(~solved)  # coarse vertices outside the solve: follow their nearest solved one
        self._carrier = np.zeros(0, dtype=np.int64)
        if len(self._carried):
            inside = np.flatnonzero(solved)
            self._carrier = inside[cKDTree(coarse.vertices[inside]).query(coarse.vertices[self._carried])[1]]

    def coarse_targets(self, targets: np.ndarray) -> np.ndarray:
        """Fine handle targets (F,H,3) float64 → the coarse handles' targets (F,Hc,3) float64 (:attr:`fixed`): the
        coarse vertex plus the mean displacement of its members (all of them handles), or plus the displacement of
        the similarity fitted to its handle members' motion (:meth:`_target_weights`). Linear in the displacements
        ``u = targets − rest`` but for the fitted rotations: one sparse product ``W u`` gives the means and the fit's
        cross-covariances, then one 3×3 SVD per partly held cluster."""
        targets = np.asarray(targets, dtype=np.float64)
        if self.level.is_identity:
            return targets
        frames, h = targets.shape[:2]
        moves = (targets - self._rest_handles).transpose(1, 0, 2).reshape(h, 3 * frames)
        weighed = (self._targets_map @ moves).reshape(-1, frames, 3).transpose(1, 0, 2)  # (F, Hc + 4m, 3)
        hc = len(self.fixed)
        out = self.level.coarse.vertices[self.fixed] + weighed[:, :hc]
        if len(self._partial):
            rows, (q_mean, qq, planar, trace) = np.searchsorted(self.fixed, self._partial), self._similarity
            m = len(self._partial)
            for f in range(frames):
                t_mean = q_mean + weighed[f, hc : hc + m]
                tq = qq + weighed[f, hc + m :].reshape(3, m, 3).transpose(1, 2, 0)  # [r, a, b] = Σ t_a qc_b
                u_svd, sigma, vt = np.linalg.svd(tq)
                flip = np.ones((m, 3))
                flip[:, 2] = np.sign(np.linalg.det(u_svd @ vt))
                rotation = np.einsum("mab,mb,mbc->mac", u_svd, flip, vt)
                scale = (sigma * flip).sum(1) / trace
                moved = t_mean - scale[:, None] * np.einsum("mab,mb->ma", rotation, q_mean)
                out[f, rows] = self.level.coarse.vertices[self._partial] + np.where(
                    planar[:, None], moved, t_mean - q_mean
                )
        return out

    def _target_weights(self) -> tuple[sp.csr_matrix, tuple[np.ndarray, ...]]:
        """What :meth:`coarse_targets` needs of the handle set, once: ``W`` (Hc + 4m, H) sparse and the fit's constant
        terms. Rows of ``W u`` (``u`` (H,3) the handles' displacements; ``m`` partly held clusters):

        - ``Hc`` rows, the mean of ``u`` over the cluster's handle members (0 for a partly held cluster);
        - ``m`` rows, the mean ``ū`` over the handles of the cluster's neighbourhood (:meth:`_neighbourhood`);
        - ``3m`` rows, ``Σ_p qc_pb u_p`` for b = 0, 1, 2, ``qc = q − q̄`` the handles' rest offsets ``q`` from the
          coarse vertex, centred.

        The similarity ``x ↦ t̄ + s R (x − q̄)`` (Umeyama) fitted to targets ``t = q + u`` has ``t̄ = q̄ + ū`` and the
        cross-covariance ``Σ (t − t̄) qcᵀ = Σ qc qcᵀ + Σ u qcᵀ`` (``Σ qc = 0``); its rotation ``R = U diag(1, 1, ±1)
        Vᵀ`` (SVD ``U Σ Vᵀ``, det R = 1), scale ``s = tr(Σ diag(1, 1, ±1)) / tr(Σ qc qcᵀ)``, and the coarse vertex
        moves by ``t̄ − s R q̄``, or by ``t̄ − q̄`` where the offsets do not span a plane (the rotation is not
        determined). Constants: ``(q̄ (m,3), Σ qc qcᵀ (m,3,3), planar (m,) bool, tr Σ qc qcᵀ (m,))``."""
        level, owner, n, h = self.level, self.level.owner[self.handles], self.level.coarse.n_vertices, len(self.handles)
        if level.is_identity:
            return sp.csr_matrix((0, h)), ()
        row_of = np.full(n, -1)
        row_of[self.fixed] = np.arange(len(self.fixed))
        full = np.ones(n, dtype=bool)
        full[self._partial] = False
        member = np.flatnonzero((row_of[owner] >= 0) & full[owner])
        rows = row_of[owner[member]]
        parts = [(rows, member, 1.0 / np.bincount(rows, minlength=len(self.fixed))[rows])]
        clusters, m = self._partial, len(self._partial)
        row, handle = self._neighbourhood(clusters)
        q = self.rest.vertices[self.handles[handle]] - level.coarse.vertices[clusters[row]]
        count = np.bincount(row, minlength=m)
        q_mean = np.stack([np.bincount(row, q[:, d], m) for d in range(3)], 1) / count[:, None]
        qc = q - q_mean[row]
        qq = np.zeros((m, 3, 3))
        for a in range(3):
            for b in range(3):
                qq[:, a, b] = np.bincount(row, qc[:, a] * qc[:, b], m)
        offset = len(self.fixed)
        parts.append((offset + row, handle, 1.0 / count[row]))
        for b in range(3):
            parts.append((offset + (1 + b) * m + row, handle, qc[:, b]))
        i, j, value = (np.concatenate(x) for x in zip(*parts))
        weights = sp.csr_matrix((value, (i, j)), shape=(offset + 4 * m, h))
        spread = np.linalg.eigvalsh(qq)
        planar = spread[:, 1] > 1e-6 * spread[:, 2]
        return weights, (q_mean, qq, planar, np.maximum(np.trace(qq, axis1=1, axis2=2), 1e-300))

    def _neighbourhood(self, clusters: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """clusters (m,) → ``(row (P,), member (P,))`` int64: the pairs of a cluster (its row in ``clusters``) and a
        handle (its index in :attr:`handles`) whose vertex lies in that cluster or in a coarse neighbour of it."""
        level, n = self.level, self.level.coarse.n_vertices
        faces = level.coarse.faces
        i, j = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
        ring = sp.csr_matrix(
            (np.ones(2 * len(i) + n, dtype=bool), (np.r_[i, j, np.arange(n)], np.r_[j, i, np.arange(n)]))
        )
        ring = sp.csr_matrix(ring, shape=(n, n))
        holds = sp.csr_matrix(
            (np.ones(len(self.handles), dtype=bool), (level.owner[self.handles], np.arange(len(self.handles)))),
            shape=(n, len(self.handles)),
        )
        pairs = (ring[clusters] @ holds).tocoo()
        return pairs.row.astype(np.int64), pairs.col.astype(np.int64)

    def solve(self, coarse_targets: np.ndarray, initial: np.ndarray | None = None, **options) -> ArapResult:
        """The coarse ARAP solve: coarse_targets (Hc,3), initial (C,3) or None → :class:`ArapResult` on the coarse
        level (``options``: those of :meth:`ArapSolver.solve`)."""
        return self.solver.solve(coarse_targets, initial=initial, **options)

    def fine(self, coarse_positions: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Deformed coarse vertices (C,3) float64 → the fine vertices (V,3) they carry (module docstring), written
        into ``out`` (V,3) float64 or float32 when given (computed in float64 either way), else a new float64 array."""
        moved = np.array(coarse_positions, dtype=np.float64)
        rotations = self.solver.vertex_rotations(moved)
        self._place_outside(moved, rotations)
        return carry(self.level, self.rest.vertices, moved, rotations, out)

    def coarse_surface(self, coarse_positions: np.ndarray) -> np.ndarray:
        """Deformed coarse vertices (C,3) float64 → the coarse level as :meth:`fine` carries it (a new (C,3)
        float64 array): the solved vertices as given, each coarse vertex outside the solve moved rigidly with its
        nearest solved one (its rotation ``R_c``: ``y_k = y_c + R_c (q_k − q_c)``), but the coarse handles
        (:attr:`fixed`), which stay as given: on their targets after a solve (a handle outside the solve is a vertex
        of no coarse face, a corner of no fine vertex)."""
        moved = np.array(coarse_positions, dtype=np.float64)
        if len(self._carried):
            self._place_outside(moved, self.solver.vertex_rotations(moved))
            moved[self.fixed] = coarse_positions[self.fixed]
        return moved

    def _place_outside(self, moved: np.ndarray, rotations: np.ndarray) -> None:
        """Move the coarse vertices outside the solve with their nearest solved one, in place: ``y_k = y_c + R_c (q_k
        − q_c)``, ``R_k = R_c``."""
        if len(self._carried):
            q, c = self.level.coarse.vertices, self._carrier
            turned = np.einsum("kab,kb->ka", rotations[c], q[self._carried] - q[c])
            moved[self._carried] = moved[c] + turned
            rotations[self._carried] = rotations[c]

    def surface(
        self, coarse_positions: np.ndarray, targets: np.ndarray, out: np.ndarray | None = None
    ) -> tuple[np.ndarray, float]:
        """Deformed coarse vertices (C,3), the fine handles' targets (H,3) → ``(fine (V,3), gap)``: the carried surface
        (:meth:`fine`, into ``out`` when given) with the handle vertices set to their targets and vertices of no face
        at rest (as the direct solve leaves them); ``gap`` is the largest distance of a carried handle vertex to its
        target."""
        positions = self.fine(coarse_positions, out)
        positions[self._stray] = self.rest.vertices[self._stray]
        gap = float(np.sqrt(((positions[self.handles] - targets) ** 2).sum(1).max(initial=0.0)))
        positions[self.handles] = targets
        return positions, gap


def carry(
    level: CoarseLevel, fine: np.ndarray, moved: np.ndarray, maps: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """The fine rest vertices ``fine (V,3)`` of ``level``, carried by its coarse vertices moved to ``moved (C,3)``
    with local linear maps ``maps (C,3,3)`` (rotations, or the Jacobians of a space map) → (V,3):
    ``p'_i = Σ_c w_ic (y_k + M_k (p_i − q_k))``, evaluated in float64 and written into ``out`` (V,3) float64 or
    float32 when given, else a new float64 array. Exact for a common affine map ``x ↦ A x + t`` (every ``y_k = A q_k
    + t``, ``M_k = A``), since each row of weights sums to 1."""
    if out is None:
        out = np.empty((len(fine), 3))
    if out.shape != (len(fine), 3) or out.dtype not in (np.float32, np.float64) or not out.flags.c_contiguous:
        raise ValueError(f"carry: out must be a C-contiguous ({len(fine)}, 3) float32 or float64 array")
    table = np.empty((len(moved), 16))  # per coarse vertex, one row of two cache lines: y_k, M_k, q_k
    table[:, :3], table[:, 3:12], table[:, 12:15] = moved, np.reshape(maps, (-1, 9)), level.coarse.vertices
    launch(_kernel.carry, fine, level.corners, level.weights, table, out)
    return out
