"""3-D mean value coordinates of a closed, consistently oriented triangle cage (Ju, Schaefer & Warren, SIGGRAPH 2005).

``mean_value_coordinates(points (P,3), vertices (C,3), faces (F,3)) → (P,C) float64``: rows sum to 1 and reproduce
linear functions (``coords @ vertices == points``); optionally the winding number ``(P,)`` for inside tests. Per
face, ``w_{i_k} += (θ_k − c_{k+1} θ_{k+2} − c_{k+2} θ_{k+1}) / (d_{i_k} sin θ_{k+1} s_{k+2})``, ``λ = w / Σ w``,
evaluated from distances without the trigonometry that loses digits near the cage. Points on a vertex, an edge
(``EDGE_EPS``) or a face (``PLANE_EPS``) get the exact interpolant there; exterior points extrapolate. Derivation:
docs/method.md, "Cage: mean value coordinates".
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from nerfedit_plugin.geometry.normals import face_normals

VERTEX_EPS = 1e-12  # ‖x − v‖ ≤ VERTEX_EPS × cage size ⇒ x is the vertex
EDGE_EPS = 1e-8  # distance to an edge ≤ EDGE_EPS × cage size ⇒ linear interpolation along the edge
PLANE_EPS = 1e-12  # distance to a face's plane ≤ PLANE_EPS × cage size ⇒ x is on the face or the face is skipped
BARY_EPS = 1e-9  # a point in a face's plane is on the face when its barycentrics are ≥ −BARY_EPS
NEAR_LINE = 1e-6  # sin²(θ/2) or cos²(θ/2) below this ⇒ θ is recomputed from unit vectors


@dataclass(frozen=True)
class CageGeometry:
    """Per-cage precomputation (coordinates centred on the vertex mean for accurate plane products)."""

    origin: np.ndarray  # (3,) subtracted from vertices and points
    vertices: np.ndarray  # (C, 3) centred
    faces: np.ndarray  # (F, 3)
    scale: float  # bounding-box diagonal
    edges: np.ndarray  # (E, 2) unique undirected edges
    lengths: np.ndarray  # (E,)
    face_edges: np.ndarray  # (F, 3): the edge opposite corner k
    normals: np.ndarray  # (F, 3) area normals (v₁ − v₀) × (v₂ − v₀)
    area2: np.ndarray  # (F,) their norms (twice the areas)
    offsets: np.ndarray  # (F,) n_f · v₀
    scatter: sp.csr_matrix  # (C, 3F): sums per-corner values into vertices (corner k of face f = row kF + f)

    @classmethod
    def of(cls, vertices: np.ndarray, faces: np.ndarray) -> CageGeometry:
        """vertices (C,3) float, faces (F,3) int → the cage's precomputed geometry (centred on the vertex mean)."""
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64)
        origin = vertices.mean(0)
        v = vertices - origin
        opposite = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1).reshape(-1, 2)
        edges, inverse = np.unique(np.sort(opposite, axis=1), axis=0, return_inverse=True)
        normals = face_normals(v, faces)
        n = len(faces)
        scatter = sp.csr_matrix((np.ones(3 * n), (faces.T.reshape(-1), np.arange(3 * n))), shape=(len(v), 3 * n))
        return cls(
            origin=origin,
            vertices=v,
            faces=faces,
            scale=max(float(np.linalg.norm(v.max(0) - v.min(0))), 1e-300),
            edges=edges,
            lengths=np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1),
            face_edges=inverse.reshape(n, 3),
            normals=normals,
            area2=np.linalg.norm(normals, axis=1),
            offsets=np.einsum("fi,fi->f", normals, v[faces[:, 0]]),
            scatter=scatter,
        )


def mean_value_coordinates(
    points: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    chunk_size: int = 64,
    workers: int = 2,
    return_winding: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Mean value coordinates ``(P, C)`` float64 of ``points (P,3)`` w.r.t. the cage ``vertices (C,3)`` float,
    ``faces (F,3)`` int (with ``return_winding``: ``(coords (P,C), winding (P,))``, both float64).

    Rows sum to 1 and reproduce linear functions: ``coords @ vertices == points``. Evaluated in chunks of
    ``chunk_size`` points on ``workers`` threads, each with a preallocated workspace of ≈ 25 · F · chunk_size
    float64 (allocation-free inner loop). The result is a Fortran-ordered view. With ``return_winding`` also
    returns the cage's winding number at each point (±1 inside, 0 outside; the sign is the orientation).
    """
    cage = CageGeometry.of(vertices, faces)
    points = np.asarray(points, dtype=np.float64) - cage.origin
    coords = np.empty((len(cage.vertices), len(points)))  # (C, P): returned transposed (a view, no copy)
    winding = np.empty(len(points))
    starts = range(0, len(points), chunk_size)
    workers = max(1, min(workers, len(starts)))

    def work(first: int) -> None:
        kernel = _Kernel(cage, min(chunk_size, len(points)), return_winding)
        with np.errstate(divide="ignore", invalid="ignore"):  # 0/0 at degenerate positions, overwritten afterwards
            for start in starts[first::workers]:
                block = slice(start, start + chunk_size)
                coords[:, block], winding[block] = kernel(points[block])

    with ThreadPoolExecutor(max_workers=workers) as pool:  # numpy releases the GIL inside the kernels
        list(pool.map(work, range(workers)))
    return (coords.T, winding) if return_winding else coords.T


class _Kernel:
    """Evaluates one chunk of points into preallocated buffers; arrays are (vertex | edge | face, point)."""

    def __init__(self, cage: CageGeometry, size: int, with_winding: bool) -> None:
        n_v, n_e, n_f = len(cage.vertices), len(cage.edges), len(cage.faces)
        self.cage, self.size, self.with_winding = cage, size, with_winding
        # per-row constants spelled out over the chunk: broadcasting a (rows, 1) operand costs numpy a buffer copy
        self.len2 = np.repeat((cage.lengths**2)[:, None], size, axis=1)
        self.plane_tol = np.repeat((PLANE_EPS * cage.scale * cage.area2)[:, None], size, axis=1)
        self.planes = np.hstack([-cage.normals, cage.offsets[:, None]])  # (F, 4) · (x, 1) = n_f·(v₀ − x)
        self.x1 = np.ones((4, size))
        self.corners = np.ascontiguousarray(cage.faces.T).reshape(-1)  # corner k of face f = row kF + f
        self.opposite = np.ascontiguousarray(cage.face_edges.T).reshape(-1)
        self.dist, self.vtmp = np.empty((2, n_v, size))
        self.da, self.db, self.num, self.den, self.both, self.half, self.sin2 = np.empty((7, n_e, size))
        self.edge_q = np.empty((3, n_e, size))  # per edge: cos θ, μ = θ / sin θ, θ sin θ
        self.face_q = np.empty((3, 3, n_f, size))  # the same for the edge opposite each corner
        self.corner_d = np.empty((3, n_f, size))
        self.dprod, self.vol, self.inv_det, self.ftmp = np.empty((4, n_f, size))
        self.in_plane = np.empty((n_f, size), dtype=bool)
        self.near = np.empty((n_e, size), dtype=bool)
        self.p = np.empty((3, n_f, size))
        self.stacked = np.empty((3, n_f, size))

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(x)
        if n < self.size:  # last chunk: pad with copies of its last point
            x = np.concatenate([x, np.repeat(x[-1:], self.size - n, axis=0)])
        on_edge = self._edges(x)
        lam, winding = self._faces(x)
        self._degenerate(x, lam, winding, on_edge)
        return lam[:, :n], winding[:n]

    def _edges(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cage, dist, vtmp = self.cage, self.dist, self.vtmp
        np.subtract(cage.vertices[:, 0, None], x[:, 0], out=dist)
        np.square(dist, out=dist)
        for i in (1, 2):
            np.subtract(cage.vertices[:, i, None], x[:, i], out=vtmp)
            np.square(vtmp, out=vtmp)
            dist += vtmp
        np.sqrt(dist, out=dist)

        da, db, num, den, both, half, sin2 = self.da, self.db, self.num, self.den, self.both, self.half, self.sin2
        np.take(dist, cage.edges[:, 0], axis=0, out=da, mode="clip")
        np.take(dist, cage.edges[:, 1], axis=0, out=db, mode="clip")
        np.subtract(da, db, out=num)
        np.square(num, out=num)
        np.subtract(self.len2, num, out=num)  # 4 d_a d_b sin²(θ/2)
        da += db
        np.square(da, out=den)
        den -= self.len2  # 4 d_a d_b cos²(θ/2)
        np.add(num, den, out=both)  # 4 d_a d_b
        cos, mu, tsin = self.edge_q
        np.subtract(den, num, out=cos)
        cos /= both
        np.divide(num, den, out=half)
        np.sqrt(half, out=half)  # tan(θ/2)
        np.multiply(half, den, out=sin2)  # sin θ / 2 = tan(θ/2) cos²(θ/2) = √(num·den) / both
        sin2 /= both
        np.arctan(half, out=half)  # θ/2: accurate away from θ ≈ 0, π (where num or den cancels)

        # θ ≈ 0 or π (x near an edge's line, min(num, den) ≤ NEAR_LINE·both): recompute those pairs from unit vectors
        np.greater(sin2, np.sqrt(NEAR_LINE * (1.0 - NEAR_LINE)), out=self.near)
        np.logical_not(self.near, out=self.near)  # also catches NaN from num or den rounding below 0
        on_edge = (cage.edges[:0, 0], cage.edges[:0, 0])
        ei, pi = np.divmod(np.flatnonzero(self.near), self.size)
        if ei.size:
            rel = [cage.vertices[cage.edges[ei, j]] - x[pi] for j in (0, 1)]
            unit = [r / dist[cage.edges[ei, j], pi][:, None] for j, r in enumerate(rel)]
            sin_half = 0.5 * np.linalg.norm(unit[0] - unit[1], axis=1)
            cos_half = 0.5 * np.linalg.norm(unit[0] + unit[1], axis=1)
            cos[ei, pi] = (cos_half - sin_half) * (cos_half + sin_half)
            half[ei, pi] = np.arctan2(sin_half, cos_half)
            sin2[ei, pi] = sin_half * cos_half
            behind = np.flatnonzero(cos_half < sin_half)  # θ ≈ π: x beside the segment, between its ends
            if behind.size:
                line_dist = np.linalg.norm(np.cross(rel[0][behind], rel[1][behind]), axis=1) / cage.lengths[ei[behind]]
                close = behind[line_dist <= EDGE_EPS * cage.scale]  # on the segment
                on_edge = (ei[close], pi[close])

        np.divide(half, sin2, out=mu)  # θ / sin θ
        np.multiply(half, sin2, out=tsin)
        tsin *= 4.0  # θ sin θ
        return on_edge

    def _faces(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cage, fq, p, ftmp = self.cage, self.face_q, self.p, self.ftmp
        n_f = len(cage.faces)
        for q in range(3):
            np.take(self.edge_q[q], self.opposite, axis=0, out=fq[q].reshape(3 * n_f, self.size), mode="clip")
        cos, mu, tsin = fq  # (3, F, P) each: index = corner

        np.take(self.dist, self.corners, axis=0, out=self.corner_d.reshape(3 * n_f, self.size), mode="clip")
        np.multiply(self.corner_d[0], self.corner_d[1], out=self.dprod)
        self.dprod *= self.corner_d[2]
        self.x1[:3] = x.T
        np.matmul(self.planes, self.x1, out=self.vol)  # n_f·(v₀ − x) = det[u₀,u₁,u₂] d₀d₁d₂
        np.abs(self.vol, out=ftmp)
        np.less_equal(ftmp, self.plane_tol, out=self.in_plane)
        np.divide(self.dprod, self.vol, out=self.inv_det)

        for k in range(3):  # P_k = cos θ_k − cos θ_{k+1} cos θ_{k+2}
            np.multiply(cos[(k + 1) % 3], cos[(k + 2) % 3], out=p[k])
            np.subtract(cos[k], p[k], out=p[k])
        for k in range(3):  # (θ_k sin θ_k − μ_{k+1} P_{k+2} − μ_{k+2} P_{k+1}) / det
            out = self.stacked[k]
            np.multiply(mu[(k + 1) % 3], p[(k + 2) % 3], out=out)
            np.subtract(tsin[k], out, out=out)
            np.multiply(mu[(k + 2) % 3], p[(k + 1) % 3], out=ftmp)
            out -= ftmp
            out *= self.inv_det
        if self.in_plane.any():
            self.stacked[:, self.in_plane] = 0.0
        w = cage.scatter @ self.stacked.reshape(-1, self.size)
        w /= self.dist
        lam = w / w.sum(0)

        winding = np.empty(self.size)
        if self.with_winding:
            np.add(cos[0], cos[1], out=ftmp)
            ftmp += cos[2]
            ftmp += 1.0
            ftmp *= self.dprod
            np.arctan2(self.vol, ftmp, out=ftmp)
            np.sum(ftmp, axis=0, out=winding)
            winding /= 2.0 * np.pi
        return lam, winding

    def _degenerate(self, x, lam, winding, on_edge) -> None:
        """Overwrite the columns of points on a face, an edge or a vertex (in increasing priority)."""
        cage = self.cage
        if self.in_plane.any():
            fi, pi = np.nonzero(self.in_plane)
            corners = cage.vertices[cage.faces[fi]] - x[pi][:, None, :]  # (K, 3, 3)
            bary = np.stack(
                [
                    np.einsum("ki,ki->k", cage.normals[fi], np.cross(corners[:, (k + 1) % 3], corners[:, (k + 2) % 3]))
                    for k in range(3)
                ],
                axis=1,
            )
            bary /= cage.area2[fi, None] ** 2
            inside = (bary >= -BARY_EPS).all(1)
            fi, pi, bary = fi[inside], pi[inside], np.clip(bary[inside], 0.0, None)
            pi, first = np.unique(pi, return_index=True)
            lam[:, pi] = 0.0
            lam[cage.faces[fi[first]].T, pi[None]] = (bary[first] / bary[first].sum(1, keepdims=True)).T
            winding[pi] = 0.5
        ei, pi = on_edge
        if ei.size:
            pi, first = np.unique(pi, return_index=True)
            a, b = cage.edges[ei[first]].T
            da, db = self.dist[a, pi], self.dist[b, pi]
            lam[:, pi] = 0.0
            lam[a, pi], lam[b, pi] = db / (da + db), da / (da + db)
            winding[pi] = 0.5
        at_vertex = self.dist <= VERTEX_EPS * cage.scale
        if np.count_nonzero(at_vertex):
            cols = np.flatnonzero(at_vertex.any(0))
            lam[:, cols] = 0.0
            lam[at_vertex[:, cols].argmax(0), cols] = 1.0
            winding[cols] = 0.5
