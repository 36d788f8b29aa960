"""Injective (flip-free) deformation of a tet mesh: symmetric Dirichlet energy, projected Newton, maximal safe step.

:class:`InjectiveSolver` minimises, over deformed positions ``X (N,3)`` of a positively oriented tet mesh (rest
``P``, tet volumes ``|t|``, deformation gradients ``J_t = D_t(X) D_t(P)⁻¹`` of the edge matrices
``D_t = [x₁ − x₀, x₂ − x₀, x₃ − x₀]``),

``E(X) = ¼ Σ_t |t| (‖J_t‖²_F + ‖J_t⁻¹‖²_F − 6) + w_c ‖C X − T‖²``  (soft linear constraints ``C (m,N)``),

the symmetric Dirichlet energy (the energy of SLIM, Rabinovich et al. 2017), which is ``+∞`` on any flat or
inverted tet and equals the ARAP energy to second order at a rotation (hence the ¼ and the same dimensionless
constraint weight ``w_c = w · mean diag(L)`` as :class:`~nerfedit_plugin.geometry.arap.ArapSolver`).
Each iteration is a projected Newton step (Teran et al. 2005: the per-tet 9×9 Hessian in ``J`` clamped to positive
eigenvalues, so the assembled system is positive definite; its eigensystem in closed form, Smith et al. 2019, from
one 3×3 SVD per tet), solved inexactly by conjugate gradients preconditioned with the rest stiffness
``2 L + 2 w_c CᵀC`` per axis (factored once; the exact Cholesky solve is the fallback when an inexact step gains
nothing), followed by a backtracking (Armijo) line search that
starts at ``0.9 ×`` the maximal flip-free step of Smith & Schaefer 2015: the smallest ``α > 0`` where a tet's
``det(D_t(X) + α D_t(ΔX)) = 0``, i.e. ``α = −1/λ`` for the real negative eigenvalues ``λ`` of
``D_t(X)⁻¹ D_t(ΔX)``. Started from positions with every tet positively oriented, every iterate stays so: the map is
injective on each tet and keeps the orientation of all of them.

The per-tet work runs in compiled (numba, serial, cached on disk) kernels: :func:`_newton_kernel` (``J``, its SVD by
one-sided Jacobi rotations, the gradient, and the projected Hessian's 3×3 blocks summed straight into the block
matrix), :func:`_distortion` (the energy) and :func:`_relative_motions` (the tets that may flatten within the line
search's first step). The numpy forms they replace (:func:`_element_hessians`, :func:`flip_free_step`) are kept as
their test oracles. The CG stays preconditioned by the rest stiffness even where that needs all
:data:`CG_MAX_ITERATIONS`: the current Newton matrix's per-axis stiffness as the preconditioner made the refined
lift of ``configs/cage_bunny_auto.json`` 3× faster, but it changes the inexact steps and with them where the
relative-decrease rule stops a slowly converging re-lift (there: a worse residual after the lift's refinement;
docs/benchmarks.md, "Inversion-free lift").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numba import njit

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.cholesky import SparseCholesky
from nerfedit_plugin.geometry.soft_constraints import Expansion, SoftConstraints
from nerfedit_plugin.geometry.tets import tet_signed_volumes

#: a tet's 6 edges (corner pairs)
_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
#: fraction of the maximal flip-free step a line search starts from (SLIM: 0.8)
SAFE_STEP = 0.9
#: Armijo sufficient-decrease constant of the line search
ARMIJO = 1e-4
#: halvings of the step before the line search gives up (no decrease left at this precision)
MAX_HALVINGS = 40
#: smallest eigenvalue kept in a projected per-tet Hessian, relative to the tet's volume
EIGEN_FLOOR = 1e-8
#: ridge added to the assembled Newton matrix, relative to its mean diagonal (keeps loose parts solvable)
RIDGE = 1e-10
#: relative residual of the conjugate-gradient Newton solves
CG_TOLERANCE = 1e-3
#: conjugate-gradient iterations per Newton solve at most
CG_MAX_ITERATIONS = 200


class InjectiveResult(NamedTuple):
    """``vertices (N,3) float64`` (every tet positively oriented); ``iterations`` done; ``energies[k]`` = E after k
    iterations (decreasing); ``converged`` = the relative decrease fell below the tolerance."""

    vertices: np.ndarray
    iterations: int
    energies: list[float]
    converged: bool


def flip_free_step(edges: np.ndarray, directions: np.ndarray, limit: float = np.inf) -> float:
    """edges (K,3,3) float64 edge matrices ``D_t`` (columns ``x_k − x_0``) with ``det > 0``, directions (K,3,3)
    float64 their change ``D_t(ΔX)`` → the largest ``α`` (``inf`` if none) such that every
    ``det(D_t + a D_t(ΔX)) > 0`` for ``0 ≤ a < α`` (Smith & Schaefer 2015): ``det(D + αΔ) = det D · det(I + α D⁻¹Δ)``
    vanishes at ``α = −1/λ`` for the eigenvalues λ of ``D⁻¹Δ``. With a finite ``limit``, tets that cannot flatten
    before it (``limit · ‖D⁻¹Δ‖_F < 1``, a bound on the spectral radius) are skipped: the answer is exact when it is
    below ``limit``, else some value ≥ ``limit`` (``inf`` if every tet was skipped)."""
    relative = np.linalg.solve(edges, directions)
    if np.isfinite(limit):
        relative = relative[limit * np.sqrt(np.einsum("kab,kab->k", relative, relative)) >= 1.0]
    return _first_flattening(relative)


def _first_flattening(relative: np.ndarray) -> float:
    """relative (K,3,3) float64 the matrices ``D⁻¹Δ`` → ``min −1/λ`` over their real negative eigenvalues λ (``inf``
    if none)."""
    if not len(relative):
        return np.inf
    eigenvalues = np.linalg.eigvals(relative)
    real = np.abs(eigenvalues.imag) <= 1e-12 * np.maximum(np.abs(eigenvalues.real), 1e-300)
    shrinking = real & (eigenvalues.real < 0)
    if not shrinking.any():
        return np.inf
    return float((-1.0 / eigenvalues.real[shrinking]).min())


def _element_hessians(u, sigma, vt, scale, gradient_map):
    """The projected 12×12 Hessians (K,12,12) of ``¼|t| Ψ(σ(J_t))`` in the corner positions, from the analytic
    eigensystem of the 9×9 Hessian in J (Smith et al. 2019): 3 scaling modes ``U e_i e_iᵀ Vᵀ`` (λ = 2 + 6σ_i⁻⁴),
    3 flip modes ``U (e_i e_jᵀ + e_j e_iᵀ) Vᵀ/√2`` (λ = 2 + 2(σ_i² + σ_iσ_j + σ_j²)/(σ_iσ_j)³) and 3 twist modes
    ``U (e_i e_jᵀ − e_j e_iᵀ) Vᵀ/√2`` (λ = 2 − 2(σ_i² − σ_iσ_j + σ_j²)/(σ_iσ_j)³: the only negative ones)."""
    values = [2.0 + 6.0 / sigma**4]
    modes = [np.einsum("kai,kib->kiab", u, vt)]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        si, sj = sigma[:, i], sigma[:, j]
        cube = (si * sj) ** 3
        a = np.einsum("ka,kb->kab", u[:, :, i], vt[:, j]) * np.sqrt(0.5)
        c = np.einsum("ka,kb->kab", u[:, :, j], vt[:, i]) * np.sqrt(0.5)
        values += [(2.0 - 2.0 * (si * si - si * sj + sj * sj) / cube)[:, None]]
        values += [(2.0 + 2.0 * (si * si + si * sj + sj * sj) / cube)[:, None]]
        modes += [(a - c)[:, None], (a + c)[:, None]]
    values = np.concatenate(values, axis=1)
    values = np.maximum(values, 2.0 * EIGEN_FLOOR) * scale[:, None]
    k = len(u)  # mode m as a 12-vector over (corner c, axis a): Σ_b Q_ab b_cb
    vectors = (np.concatenate(modes, axis=1).reshape(k, 27, 3) @ gradient_map.transpose(0, 2, 1)).reshape(k, 9, 3, 4)
    vectors = vectors.transpose(0, 1, 3, 2).reshape(k, 9, 12)
    return (vectors * values[:, :, None]).transpose(0, 2, 1) @ vectors


@njit(cache=True)
def _svd3(a, u, s, v):
    """a (3,3) float64 → u, s, v filled: a = u diag(s) vᵀ by one-sided Jacobi (Hestenes) rotations: s ≥ 0 to high
    relative accuracy, v a rotation (det = 1), so det u = sign(det a) where s > 0; s unordered."""
    w = a.copy()
    for i in range(3):
        for j in range(3):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(40):
        rotated = False
        for pair in range(3):
            p = 0 if pair < 2 else 1
            q = 1 if pair == 0 else 2
            alpha = w[0, p] * w[0, p] + w[1, p] * w[1, p] + w[2, p] * w[2, p]
            beta = w[0, q] * w[0, q] + w[1, q] * w[1, q] + w[2, q] * w[2, q]
            gamma = w[0, p] * w[0, q] + w[1, p] * w[1, q] + w[2, p] * w[2, q]
            if abs(gamma) <= 1e-15 * np.sqrt(alpha * beta):
                continue
            rotated = True
            zeta = (beta - alpha) / (2.0 * gamma)
            t = (1.0 if zeta >= 0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
            c = 1.0 / np.sqrt(1.0 + t * t)
            sn = c * t
            for i in range(3):
                wp, wq = w[i, p], w[i, q]
                w[i, p], w[i, q] = c * wp - sn * wq, sn * wp + c * wq
                vp, vq = v[i, p], v[i, q]
                v[i, p], v[i, q] = c * vp - sn * vq, sn * vp + c * vq
        if not rotated:
            break
    for j in range(3):
        s[j] = np.sqrt(w[0, j] * w[0, j] + w[1, j] * w[1, j] + w[2, j] * w[2, j])
        for i in range(3):
            u[i, j] = w[i, j] / s[j] if s[j] > 0 else 0.0


@njit(cache=True)
def _relative_motions(x, step, tets, limit):
    """positions ``x (N,3)`` (every tet positively oriented), ``step (N,3)``, ``limit`` → the matrices ``D_t(x)⁻¹
    D_t(step)`` (M,3,3) of the tets that may flatten before ``limit`` (``limit · ‖D⁻¹Δ‖_F ≥ 1``; all if ``limit`` is
    ``inf``): :func:`flip_free_step`'s candidates, compiled (``D⁻¹`` by cofactors)."""
    out = np.empty((tets.shape[0], 3, 3))
    count = 0
    edges, change, inverse = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for k in range(tets.shape[0]):
        for a in range(3):
            for c in range(3):
                edges[a, c] = x[tets[k, c + 1], a] - x[tets[k, 0], a]
                change[a, c] = step[tets[k, c + 1], a] - step[tets[k, 0], a]
        for r in range(3):  # row r of D⁻¹: (column r+1 × column r+2) / det
            p, q = (r + 1) % 3, (r + 2) % 3
            inverse[r, 0] = edges[1, p] * edges[2, q] - edges[2, p] * edges[1, q]
            inverse[r, 1] = edges[2, p] * edges[0, q] - edges[0, p] * edges[2, q]
            inverse[r, 2] = edges[0, p] * edges[1, q] - edges[1, p] * edges[0, q]
        det = inverse[0, 0] * edges[0, 0] + inverse[0, 1] * edges[1, 0] + inverse[0, 2] * edges[2, 0]
        norm = 0.0
        for a in range(3):
            for c in range(3):
                value = inverse[a, 0] * change[0, c] + inverse[a, 1] * change[1, c] + inverse[a, 2] * change[2, c]
                value /= det
                out[count, a, c] = value
                norm += value * value
        if limit * np.sqrt(norm) >= 1.0:
            count += 1
    return out[:count]


@njit(cache=True)
def _block_slots(indptr, indices, rows, columns):
    """The position in a canonical CSR pattern (``indptr``, sorted ``indices``) of each entry ``(rows[p],
    columns[p])`` (present), by bisection in its row."""
    out = np.empty(len(rows), dtype=np.int64)
    for p in range(len(rows)):
        low, high = indptr[rows[p]], indptr[rows[p] + 1]
        while low < high:
            middle = (low + high) // 2
            if indices[middle] < columns[p]:
                low = middle + 1
            else:
                high = middle
        out[p] = low
    return out


@njit(cache=True, inline="always")
def _jacobian(x, tet, b, jac):
    """``J = Σ_c x_{tet[c]} ⊗ b_c`` (3×3, into ``jac``): the tet's deformation gradient from its gradient map ``b``."""
    for a in range(3):
        for e in range(3):
            total = 0.0
            for c in range(4):
                total += x[tet[c], a] * b[c, e]
            jac[a, e] = total


@njit(cache=True)
def _newton_kernel(x, tets, gradient_map, scale, slots, floor, blocks, gradient):
    """The per-tet work of a Newton iteration, compiled: for each tet, ``J = Σ_c x_c ⊗ b_c``, its SVD
    (:func:`_svd3`), the gradient ``b_c · (∂E/∂J)ᵀ`` added into ``gradient (N,3)`` and the projected 12×12 Hessian
    of :func:`_element_hessians` (same eigensystem, eigenvalues clamped at ``floor``, times ``scale``) added as 16
    corner-pair 3×3 blocks into ``blocks (B,3,3)`` at ``slots (K,16)`` (pair ``4 c + d``)."""
    jac, u, s, v = np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    w = np.empty((4, 3))
    modes = np.empty((9, 4, 3))
    values = np.empty(9)
    half = np.sqrt(0.5)
    for k in range(tets.shape[0]):
        b = gradient_map[k]
        _jacobian(x, tets[k], b, jac)
        _svd3(jac, u, s, v)
        for c in range(4):  # W = b V: the corners' gradients in the right singular frame
            for j in range(3):
                w[c, j] = b[c, 0] * v[0, j] + b[c, 1] * v[1, j] + b[c, 2] * v[2, j]
        for c in range(4):  # gradient: Σ_i ψ_i U[:, i] W[c, i], ψ_i = ¼|t| (2σ_i − 2σ_i⁻³)
            node = tets[k, c]
            for i in range(3):
                psi = scale[k] * (2.0 * s[i] - 2.0 / s[i] ** 3) * w[c, i]
                for a in range(3):
                    gradient[node, a] += psi * u[a, i]
        for i in range(3):  # scaling modes U e_i e_iᵀ Vᵀ
            values[i] = 2.0 + 6.0 / s[i] ** 4
            for c in range(4):
                for a in range(3):
                    modes[i, c, a] = u[a, i] * w[c, i]
        m = 3
        for i in range(3):
            for j in range(i + 1, 3):
                si, sj = s[i], s[j]
                cube = (si * sj) ** 3
                values[m] = 2.0 - 2.0 * (si * si - si * sj + sj * sj) / cube  # twist
                values[m + 1] = 2.0 + 2.0 * (si * si + si * sj + sj * sj) / cube  # flip
                for c in range(4):
                    for a in range(3):
                        first, second = u[a, i] * w[c, j] * half, u[a, j] * w[c, i] * half
                        modes[m, c, a] = first - second
                        modes[m + 1, c, a] = first + second
                m += 2
        for i in range(9):
            values[i] = max(values[i], floor) * scale[k]
        for c in range(4):  # the blocks (c, d ≥ c) and their transposes (d, c)
            for d in range(c, 4):
                slot, mirror = slots[k, 4 * c + d], slots[k, 4 * d + c]
                for a in range(3):
                    for e in range(3):
                        total = 0.0
                        for i in range(9):
                            total += values[i] * modes[i, c, a] * modes[i, d, e]
                        blocks[slot, a, e] += total
                        if d != c:
                            blocks[mirror, e, a] += total


@njit(cache=True)
def _distortion(x, tets, gradient_map, volumes):
    """``¼ Σ_t |t| (‖J_t‖²_F + ‖J_t⁻¹‖²_F − 6)`` at ``x (N,3)``, compiled (``‖J⁻¹‖² = ‖cof J‖² / det²``); ``inf``
    as soon as a tet has ``det J ≤ 0``."""
    jac = np.empty((3, 3))
    total = 0.0
    for k in range(tets.shape[0]):
        b = gradient_map[k]
        _jacobian(x, tets[k], b, jac)
        c00 = jac[1, 1] * jac[2, 2] - jac[1, 2] * jac[2, 1]
        c01 = jac[1, 2] * jac[2, 0] - jac[1, 0] * jac[2, 2]
        c02 = jac[1, 0] * jac[2, 1] - jac[1, 1] * jac[2, 0]
        det = jac[0, 0] * c00 + jac[0, 1] * c01 + jac[0, 2] * c02
        if not det > 0:
            return np.inf
        c10 = jac[0, 2] * jac[2, 1] - jac[0, 1] * jac[2, 2]
        c11 = jac[0, 0] * jac[2, 2] - jac[0, 2] * jac[2, 0]
        c12 = jac[0, 1] * jac[2, 0] - jac[0, 0] * jac[2, 1]
        c20 = jac[0, 1] * jac[1, 2] - jac[0, 2] * jac[1, 1]
        c21 = jac[0, 2] * jac[1, 0] - jac[0, 0] * jac[1, 2]
        c22 = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
        cof = c00 * c00 + c01 * c01 + c02 * c02 + c10 * c10 + c11 * c11 + c12 * c12 + c20 * c20 + c21 * c21
        cof += c22 * c22
        frob = 0.0
        for a in range(3):
            for e in range(3):
                frob += jac[a, e] * jac[a, e]
        total += volumes[k] * (frob + cof / (det * det) - 6.0)
    return 0.25 * total


class InjectiveSolver:
    """Flip-free minimiser of the symmetric Dirichlet energy plus soft linear constraints on a tet mesh (see the
    module docstring). ``vertices (N,3) float64`` rest (every tet positively oriented), ``tets (K,4) int64``,
    ``constraints`` a sparse ``C (m,N)`` (or a SoftConstraints holding it, sharing its ``CᵀC``),
    ``constraint_weight`` the dimensionless ``w`` (``w_c = w · mean diag L``, ``L`` the cotangent Laplacian: as in
    ArapSolver). The sparsity pattern of the Newton matrix (with each tet's
    16 block slots) and the preconditioner's factorisation are built once; each iteration assembles the matrix
    (compiled) and solves it by preconditioned conjugate gradients."""

    def __init__(
        self,
        vertices: np.ndarray,
        tets: np.ndarray,
        constraints: sp.spmatrix | SoftConstraints,
        constraint_weight: float,
    ) -> None:
        rest = np.asarray(vertices, dtype=np.float64)
        tets = np.asarray(tets, dtype=np.int64)
        volumes = tet_signed_volumes(rest, tets)
        if not (volumes > 0).all():
            raise NerfEditError("injective solver: every rest tet must be positively oriented with a positive volume")
        self.n_vertices, self.tets, self.volumes = len(rest), tets, volumes
        self.origin = rest.mean(0)
        edges = self.edge_matrices(rest)  # D⁻¹ = [c₂ × c₃; c₃ × c₁; c₁ × c₂] / det D for the columns c_i of D
        columns = edges.transpose(0, 2, 1)
        cofactors = np.stack([np.cross(columns[:, (k + 1) % 3], columns[:, (k + 2) % 3]) for k in range(3)], axis=1)
        self.inverse_rest = cofactors / np.einsum("kd,kd->k", columns[:, 0], cofactors[:, 0])[:, None, None]
        # dJ/dx: J = Σ_c x_c ⊗ b_c with b_0 = −Σ rows of D(P)⁻¹, b_c = row c−1 (K,4,3)
        self.gradient_map = np.ascontiguousarray(
            np.concatenate([-self.inverse_rest.sum(1, keepdims=True), self.inverse_rest], axis=1)
        )
        # cotangent weights w_ij = −|t| ∇φ_i·∇φ_j of the 6 edges (∇φ_c = b_c) and the Laplacian's diagonal Σ|t| |b_c|²
        b = self.gradient_map
        weights = -volumes[:, None] * np.einsum("kpd,kpd->kp", b[:, _EDGES[:, 0]], b[:, _EDGES[:, 1]])
        n = len(rest)
        diagonal = np.bincount(tets.ravel(), (volumes[:, None] * np.einsum("kcd,kcd->kc", b, b)).ravel(), minlength=n)
        self._soft = constraints if isinstance(constraints, SoftConstraints) else SoftConstraints(constraints)
        self.constraints = self._soft.matrix
        self.constraint_weight = float(constraint_weight) * float(diagonal[np.unique(tets)].mean())
        # Newton matrix as 3×3 blocks per vertex pair (BSR): every tet's 16 corner pairs, the pairs of CᵀC and the
        # diagonal; each iteration sums the tets' blocks into their slots (compiled, _newton_kernel)
        gram = self._soft.gram
        gram_coo = gram.tocoo()
        pairs_i = np.concatenate([np.repeat(tets, 4, axis=1).ravel(), gram_coo.row, np.arange(n)])
        pairs_j = np.concatenate([np.tile(tets, (1, 4)).ravel(), gram_coo.col, np.arange(n)])
        pattern = sp.csr_matrix((np.ones(len(pairs_i)), (pairs_i, pairs_j)), shape=(n, n))
        pattern.sum_duplicates()  # canonical: sorted column indices per row
        self._indptr, self._indices = pattern.indptr.astype(np.int32), pattern.indices.astype(np.int32)
        inverse = _block_slots(pattern.indptr, pattern.indices, pairs_i, pairs_j)  # each pair's block
        n_element = 16 * len(tets)
        self._slots = np.ascontiguousarray(inverse[:n_element].reshape(len(tets), 16))  # tet's pair 4c+d → block
        self._constant = np.zeros((pattern.nnz, 3, 3))
        constant = np.bincount(inverse[n_element : n_element + gram_coo.nnz], gram_coo.data, minlength=pattern.nnz)
        self._constant[:, range(3), range(3)] = 2.0 * self.constraint_weight * constant[:, None]
        self._diagonal_blocks = inverse[-n:]
        # preconditioner of the Newton systems: the Hessian at rest without its zero rotation modes, per axis,
        # 2 L + 2 w_c CᵀC (L the cotangent Laplacian: xᵀLx = Σ|t| ‖J‖²), factored once
        i, j = tets[:, _EDGES[:, 0]].ravel(), tets[:, _EDGES[:, 1]].ravel()
        adjacency = sp.csr_matrix((weights.ravel(), (i, j)), shape=(n, n))
        laplacian = sp.diags(diagonal) - adjacency - adjacency.T
        stiffness = 2.0 * (laplacian + self.constraint_weight * gram).tocsr()
        stiffness += sp.diags(np.full(n, RIDGE * stiffness.diagonal().mean() + 1e-300))
        self._preconditioner = SparseCholesky(sp.csr_matrix(stiffness))

    def edge_matrices(self, positions: np.ndarray) -> np.ndarray:
        """positions (N,3) float64 → (K,3,3) float64 ``D_t`` (column k = ``x_{k+1} − x_0``)."""
        corners = positions[self.tets]
        return (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)

    def jacobians(self, positions: np.ndarray) -> np.ndarray:
        """positions (N,3) float64 → (K,3,3) float64 deformation gradients ``J_t``."""
        return self.edge_matrices(positions) @ self.inverse_rest

    def energy(self, positions: np.ndarray, targets: np.ndarray) -> float:
        """positions (N,3) float64, targets (m,3) float64 → E (``inf`` if a tet is flat or inverted)."""
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        return self._energy(positions, self._soft.expand(positions, targets))

    def _energy(self, positions: np.ndarray, penalty: Expansion) -> float:
        """E at positions (N,3) float64 with the constraint targets bound in ``penalty``."""
        distortion = _distortion(np.ascontiguousarray(positions), self.tets, self.gradient_map, self.volumes)
        if not np.isfinite(distortion):
            return np.inf
        return distortion + self.constraint_weight * penalty.value(positions)

    def _newton_system(self, positions: np.ndarray, penalty: Expansion) -> tuple[sp.bsr_matrix, np.ndarray]:
        """The projected Newton matrix (3N,3N) and the gradient (3N,) at ``positions``."""
        gradient = np.zeros((self.n_vertices, 3))
        summed = self._constant.copy()
        x = np.ascontiguousarray(positions)
        scale, floor = 0.25 * self.volumes, 2.0 * EIGEN_FLOOR
        _newton_kernel(x, self.tets, self.gradient_map, scale, self._slots, floor, summed, gradient)
        gradient += 2.0 * self.constraint_weight * penalty.gradient(positions)
        diagonal = summed[self._diagonal_blocks]
        ridge = RIDGE * np.einsum("kii->", diagonal) / (3 * len(diagonal))
        summed[self._diagonal_blocks] += ridge * np.eye(3)
        size = 3 * self.n_vertices
        matrix = sp.bsr_matrix((summed, self._indices, self._indptr), shape=(size, size))
        return matrix, gradient.ravel()

    def _direction(self, matrix: sp.bsr_matrix, gradient: np.ndarray, exact: bool = False) -> np.ndarray:
        """``matrix⁻¹ gradient`` (3N,): by a sparse Cholesky factorisation if ``exact``, else by conjugate gradients
        preconditioned with the rest stiffness, to a relative residual of :data:`CG_TOLERANCE` (an inexact Newton
        step; any CG iterate is a descent direction)."""
        if exact:
            return SparseCholesky(matrix.tocsr()).solve(gradient)
        precondition = lambda r: self._preconditioner.solve(r.reshape(-1, 3)).ravel()  # noqa: E731
        out, residual = np.zeros_like(gradient), gradient.copy()
        z = precondition(residual)
        direction, rz = z.copy(), float(residual @ z)
        bound = (CG_TOLERANCE * np.linalg.norm(gradient)) ** 2
        for _ in range(CG_MAX_ITERATIONS):
            product = matrix @ direction
            step = rz / float(direction @ product)
            out += step * direction
            residual -= step * product
            if float(residual @ residual) <= bound:
                break
            z = precondition(residual)
            rz, previous = float(residual @ z), rz
            direction = z + (rz / previous) * direction
        return out

    def _line_search(self, x, step, penalty, energy, slope) -> tuple[float, float]:
        """Backtracking from ``SAFE_STEP ×`` the maximal flip-free step along ``step`` (at most 1) → (α, E(x + α
        step)) of the first α meeting the Armijo condition for ``slope`` (the directional derivative), or (0, E) if
        :data:`MAX_HALVINGS` halvings found none."""
        safe = _first_flattening(_relative_motions(x, step, self.tets, 1.0 / SAFE_STEP))
        alpha = min(1.0, SAFE_STEP * safe)
        for _ in range(MAX_HALVINGS):
            trial_energy = self._energy(x + alpha * step, penalty)
            if trial_energy <= energy + ARMIJO * alpha * slope:
                return alpha, trial_energy
            alpha *= 0.5
        return 0.0, energy

    def solve(
        self,
        initial: np.ndarray,
        targets: np.ndarray,
        *,
        max_iterations: int = 50,
        tolerance: float = 1e-6,
        stop=None,
    ) -> InjectiveResult:
        """Minimise E from ``initial (N,3)`` float64 (every tet positively oriented, else :class:`NerfEditError`)
        towards constraint targets ``targets (m,3)`` float64 → :class:`InjectiveResult`. Stops when the relative
        energy decrease of an iteration is ≤ ``tolerance``, after ``max_iterations``, or when ``stop(positions)``
        (optional) returns True after an iteration."""
        x = np.array(initial, dtype=np.float64) - self.origin
        penalty = self._soft.expand(x, targets, self.origin)
        energy = self._energy(x, penalty)
        if not np.isfinite(energy):
            raise NerfEditError("injective solver: the initial positions have flat or inverted tets")
        energies, converged, exact = [energy], False, False
        while len(energies) <= max_iterations and not converged:
            matrix, gradient = self._newton_system(x, penalty)
            step = -self._direction(matrix, gradient, exact).reshape(-1, 3)
            slope = float(gradient @ step.ravel())
            if slope >= 0:  # not a descent direction at this precision: at the minimum (checked with the exact step)
                converged, exact = exact, True
                continue
            alpha, trial_energy = self._line_search(x, step, penalty, energy, slope)
            if alpha == 0:  # no decrease along the inexact step: try the exact one; none along that: at the minimum
                converged, exact = exact, True
                continue
            decrease = energy - trial_energy
            x, energy = x + alpha * step, trial_energy
            energies.append(energy)
            converged = decrease <= tolerance * abs(energies[-2])
            if stop is not None and stop(x + self.origin):
                break
        return InjectiveResult(x + self.origin, len(energies) - 1, energies, bool(converged))
