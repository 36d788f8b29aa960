"""Green coordinates of a closed, outward-oriented triangle cage (Lipman, Levin & Cohen-Or, SIGGRAPH 2008).

``green_coordinates(points (P,3), vertices (C,3), faces (F,3)) → (phi (P,C), psi (P,F))`` float64 for points inside
the cage; a deformed cage maps ``x ↦ x' = Σ_i φ_i v'_i + Σ_j ψ_j s_j n'_j`` (:func:`green_deform`; ``n'_j`` the
deformed unit normals, ``s_j`` the faces' stretch factors): exact for similarities, quasi-conformal otherwise,
defined inside the cage only. The integrals are evaluated in closed form (no per-face quadrature); derivation:
docs/method.md, "Cage: Green coordinates".
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from deformers.cage.mean_value import CageGeometry


def _skew(e: np.ndarray) -> np.ndarray:
    """Matrices ``M`` with ``M @ x = x × e`` for vectors ``e (..., 3)``."""
    zero = np.zeros(e.shape[:-1])
    return np.stack(
        [
            np.stack([zero, e[..., 2], -e[..., 1]], -1),
            np.stack([-e[..., 2], zero, e[..., 0]], -1),
            np.stack([e[..., 1], -e[..., 0], zero], -1),
        ],
        -2,
    )


def green_coordinates(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *, chunk_size: int = 32, workers: int = 2
):
    """Green coordinates ``(phi (P, C), psi (P, F))`` float64 of interior ``points (P,3)`` w.r.t. the cage
    ``vertices (C,3)`` float, ``faces (F,3)`` int; faces must face outward.

    Evaluated in chunks of ``chunk_size`` points on ``workers`` threads. Both results are Fortran-ordered views of
    ``(C, P)`` / ``(F, P)`` arrays.
    """
    cage = CageGeometry.of(vertices, faces)
    points = np.asarray(points, dtype=np.float64) - cage.origin
    v, f = cage.vertices, cage.faces
    n_faces = len(f)
    unit = cage.normals / cage.area2[:, None]
    start_v, end_v = v[f], v[np.roll(f, -1, axis=1)]  # (F, 3 edges, 3): edge m runs from corner m to m+1
    edge = end_v - start_v
    ell = np.linalg.norm(edge, axis=2).T[:, :, None]  # (3, F, 1)
    # q_m = v_{m+1} × v_m = V_{m+1} × V_m + x × e_m;  t_m ℓ_m = n·(v_m × v_{m+1}) = n·(V_m × V_{m+1}) − x·(e_m × n)
    q_const = np.cross(end_v, start_v).transpose(1, 2, 0)[..., None]  # (3 edges, 3 comps, F, 1)
    q_lin = _skew(edge).transpose(1, 2, 0, 3).reshape(-1, 3)  # rows (edge, comp, face)
    t_const = np.einsum("fi,fmi->mf", unit, np.cross(start_v, end_v))[..., None]
    t_lin = np.cross(edge, unit[:, None, :]).transpose(1, 0, 2).reshape(-1, 3)
    ends = np.stack([f, np.roll(f, -1, axis=1)]).transpose(0, 2, 1)  # (2, 3 edges, F) vertex indices

    phi = np.empty((len(v), len(points)))
    psi = np.empty((n_faces, len(points)))

    def chunk(start: int) -> None:
        x = points[start : start + chunk_size]
        block, n = slice(start, start + len(x)), len(x)
        dist = np.sqrt(((v[:, None, :] - x[None]) ** 2).sum(-1))  # (C, P)
        da, db = dist[ends[0]], dist[ends[1]]  # (3, F, P)
        tot = da + db
        log_r = np.log((tot + ell) / (tot - ell))
        cos = (da * da + db * db - ell * ell) / (2.0 * da * db)  # angle each edge subtends at x
        vol = cage.offsets[:, None] - cage.normals @ x.T  # det[v₀, v₁, v₂]
        solid = 2.0 * np.arctan2(vol, da[0] * da[1] * da[2] * (1.0 + cos.sum(0)))
        t = (t_const - (t_lin @ x.T).reshape(3, n_faces, n)) / ell
        psi[:, block] = ((t * log_r).sum(0) - np.abs(vol / cage.area2[:, None] * solid)) / (4.0 * np.pi)

        q = q_const + (q_lin @ x.T).reshape(3, 3, n_faces, n)  # (edge, comp, F, P)
        w = -unit.T[:, :, None] * psi[None, :, block] - np.einsum("mcfp,mfp->cfp", q, log_r / ell) / (4.0 * np.pi)
        corners = -np.roll(np.einsum("mcfp,cfp->mfp", q, w), -1, axis=0) / vol  # corner l uses edge l+1
        phi[:, block] = cage.scatter @ corners.reshape(3 * n_faces, n)

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:  # numpy releases the GIL in the kernels
        list(pool.map(chunk, range(0, len(points), chunk_size)))
    return phi.T, psi.T


def green_face_terms(rest: np.ndarray, deformed: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """rest (C,3), deformed (C,3) float, faces (F,3) int → ``s_j n'_j (F,3)`` float64: the deformed unit normals
    scaled by the faces' stretch factors ``s_j``."""
    u, w = rest[faces[:, 1]] - rest[faces[:, 0]], rest[faces[:, 2]] - rest[faces[:, 0]]
    ud, wd = deformed[faces[:, 1]] - deformed[faces[:, 0]], deformed[faces[:, 2]] - deformed[faces[:, 0]]

    def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.einsum("fi,fi->f", a, b)

    area = np.linalg.norm(np.cross(u, w), axis=1) / 2.0
    stretch = np.sqrt(dot(ud, ud) * dot(w, w) - 2.0 * dot(ud, wd) * dot(u, w) + dot(wd, wd) * dot(u, u)) / (
        np.sqrt(8.0) * area
    )
    normal = np.cross(ud, wd)
    return stretch[:, None] * normal / np.linalg.norm(normal, axis=1, keepdims=True)


def green_deform(
    phi: np.ndarray, psi: np.ndarray, rest: np.ndarray, deformed: np.ndarray, faces: np.ndarray
) -> np.ndarray:
    """phi (P,C), psi (P,F), rest (C,3), deformed (C,3), faces (F,3) → ``x' = φ v' + ψ (s n')`` (P,3) float64, the
    deformed positions of the points whose coordinates are ``phi``, ``psi``."""
    return phi @ deformed + psi @ green_face_terms(rest, deformed, faces)
