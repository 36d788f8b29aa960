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
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.arap import cotangent_weights
from nerfedit_plugin.geometry.cholesky import SparseCholesky
from nerfedit_plugin.geometry.tets import tet_signed_volumes

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


class InjectiveSolver:
    """Flip-free minimiser of the symmetric Dirichlet energy plus soft linear constraints on a tet mesh (see the
    module docstring). ``vertices (N,3) float64`` rest (every tet positively oriented), ``tets (K,4) int64``,
    ``constraints`` a sparse ``C (m,N)``, ``constraint_weight`` the dimensionless ``w`` (``w_c = w · mean diag L``,
    ``L`` the cotangent Laplacian: as in ArapSolver). The sparsity pattern of the Newton matrix and the
    preconditioner's factorisation are built once; each iteration assembles the matrix and solves it by
    preconditioned conjugate gradients."""

    def __init__(self, vertices: np.ndarray, tets: np.ndarray, constraints: sp.spmatrix, constraint_weight: float):
        rest = np.asarray(vertices, dtype=np.float64)
        tets = np.asarray(tets, dtype=np.int64)
        volumes = tet_signed_volumes(rest, tets)
        if not (volumes > 0).all():
            raise NerfEditError("injective solver: every rest tet must be positively oriented with a positive volume")
        self.n_vertices, self.tets, self.volumes = len(rest), tets, volumes
        self.origin = rest.mean(0)
        self.inverse_rest = np.linalg.inv(self.edge_matrices(rest))  # D_t(P)⁻¹ (K,3,3)
        # dJ/dx: J = Σ_c x_c ⊗ b_c with b_0 = −Σ rows of D(P)⁻¹, b_c = row c−1 (K,4,3)
        self.gradient_map = np.concatenate([-self.inverse_rest.sum(1, keepdims=True), self.inverse_rest], axis=1)
        weights = cotangent_weights(rest, tets)
        diagonal = np.zeros(len(rest))
        for column, (i, j) in enumerate(((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))):
            np.add.at(diagonal, tets[:, i], weights[:, column])
            np.add.at(diagonal, tets[:, j], weights[:, column])
        self.constraints = sp.csr_matrix(constraints, dtype=np.float64)
        self.constraint_weight = float(constraint_weight) * float(diagonal[np.unique(tets)].mean())
        # Newton matrix as 3×3 blocks per vertex pair (BSR): every tet's 16 corner pairs, the pairs of CᵀC and the
        # diagonal; each iteration sums the tets' blocks into their slots by one sparse product
        n = len(rest)
        gram = (self.constraints.T @ self.constraints).tocoo()
        pairs_i = np.concatenate([np.repeat(tets, 4, axis=1).ravel(), gram.row, np.arange(n)])
        pairs_j = np.concatenate([np.tile(tets, (1, 4)).ravel(), gram.col, np.arange(n)])
        unique, inverse = np.unique(pairs_i * n + pairs_j, return_inverse=True)
        inverse = inverse.ravel()
        n_blocks, n_element = len(unique), 16 * len(tets)
        self._gather = sp.csr_matrix(
            (np.ones(n_element), (inverse[:n_element], np.arange(n_element))), shape=(n_blocks, n_element)
        )
        self._constant = np.zeros((n_blocks, 3, 3))
        np.add.at(
            self._constant,
            inverse[n_element : n_element + gram.nnz],
            2.0 * self.constraint_weight * gram.data[:, None, None] * np.eye(3),
        )
        self._indptr = np.searchsorted(unique // n, np.arange(n + 1)).astype(np.int32)  # sorted: block CSR
        self._indices = (unique % n).astype(np.int32)
        self._diagonal_blocks = inverse[-n:]
        # preconditioner of the Newton systems: the Hessian at rest without its zero rotation modes, per axis,
        # 2 L + 2 w_c CᵀC (L the cotangent Laplacian: xᵀLx = Σ|t| ‖J‖²), factored once
        i, j = tets[:, [0, 0, 0, 1, 1, 2]].ravel(), tets[:, [1, 2, 3, 2, 3, 3]].ravel()
        adjacency = sp.coo_matrix((weights.ravel(), (i, j)), shape=(n, n)).tocsr()
        laplacian = sp.diags(diagonal) - adjacency - adjacency.T
        stiffness = 2.0 * (laplacian + self.constraint_weight * (self.constraints.T @ self.constraints)).tocsr()
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
        jac = self.jacobians(positions)
        det = np.linalg.det(jac)
        if not (det > 0).all():
            return np.inf
        inverse = np.linalg.inv(jac)
        distortion = np.einsum("kab,kab->k", jac, jac) + np.einsum("kab,kab->k", inverse, inverse) - 6.0
        penalty = self.constraints @ positions - targets
        return 0.25 * float(self.volumes @ distortion) + self.constraint_weight * float(np.sum(penalty * penalty))

    def _newton_system(self, positions: np.ndarray, targets: np.ndarray) -> tuple[sp.bsr_matrix, np.ndarray]:
        """The projected Newton matrix (3N,3N) and the gradient (3N,) at ``positions``."""
        jac = self.jacobians(positions)
        u, sigma, vt = np.linalg.svd(jac)  # J = U diag(σ) Vᵀ, σ > 0 on positively oriented tets
        scale = 0.25 * self.volumes
        # ∂E/∂J = ¼|t| U diag(Ψ_i) Vᵀ with Ψ(σ) = Σ σ_i² + σ_i⁻², Ψ_i = 2σ_i − 2σ_i⁻³
        stress = (u * (scale[:, None] * (2.0 * sigma - 2.0 / sigma**3))[:, None, :]) @ vt
        b = self.gradient_map
        element = _element_hessians(u, sigma, vt, scale, b)
        gradient = np.zeros((self.n_vertices, 3))
        np.add.at(gradient, self.tets, b @ stress.transpose(0, 2, 1))
        gradient += 2.0 * self.constraint_weight * (self.constraints.T @ (self.constraints @ positions - targets))
        k = len(self.tets)  # element rows/columns are (corner, axis): regroup as 16 corner-pair blocks of 3×3
        blocks = element.reshape(k, 4, 3, 4, 3).transpose(0, 1, 3, 2, 4).reshape(16 * k, 9)
        summed = (self._gather @ blocks).reshape(-1, 3, 3) + self._constant
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
        row_sums = np.asarray(self.constraints.sum(1)).reshape(-1, 1)
        targets = np.asarray(targets, dtype=np.float64) - row_sums * self.origin
        energy = self.energy(x, targets)
        if not np.isfinite(energy):
            raise NerfEditError("injective solver: the initial positions have flat or inverted tets")
        energies, converged, exact = [energy], False, False
        while len(energies) <= max_iterations and not converged:
            matrix, gradient = self._newton_system(x, targets)
            step = -self._direction(matrix, gradient, exact).reshape(-1, 3)
            slope = float(gradient @ step.ravel())
            if slope >= 0:  # not a descent direction at this precision: at the minimum (checked with the exact step)
                converged, exact = exact, True
                continue
            safe = flip_free_step(self.edge_matrices(x), self.edge_matrices(step), limit=1.0 / SAFE_STEP)
            alpha = min(1.0, SAFE_STEP * safe)
            for _ in range(MAX_HALVINGS):
                trial = x + alpha * step
                trial_energy = self.energy(trial, targets)
                if trial_energy <= energy + ARMIJO * alpha * slope:
                    break
                alpha *= 0.5
            else:  # no decrease along the inexact step: try the exact one; none along that: at the minimum
                converged, exact = exact, True
                continue
            decrease = energy - trial_energy
            x, energy = trial, trial_energy
            energies.append(energy)
            converged = decrease <= tolerance * abs(energies[-2])
            if stop is not None and stop(x + self.origin):
                break
        return InjectiveResult(x + self.origin, len(energies) - 1, energies, bool(converged))
