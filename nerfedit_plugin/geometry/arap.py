"""As-rigid-as-possible deformation (Sorkine & Alexa, SGP 2007) of triangle and tetrahedral meshes.

:class:`ArapSolver` minimises, over deformed positions ``X (N,3)`` (rest ``P``), with cotangent weights ``w_ij`` and
one rotation ``R_g`` per rotation group ``g`` (``energy``: ``spokes_and_rims``, ``spokes`` or ``elements``),
``E(X) = min_R Σ_g Σ_{(i,j)∈g} w_ij ‖(x_i − x_j) − R_g (p_i − p_j)‖²  (+ w_c ‖C X − T‖², soft constraints C (m,N))``.
Fixed vertices are eliminated exactly; local/global iterations share one prefactored sparse Cholesky and are
accelerated under an energy guard (the energy never increases): Anderson acceleration, or L-BFGS on E with the
prefactored system as initial inverse Hessian (``method``). Covariances, rotations, energy and the
global step's right-hand side come from the elements in compiled kernels (:mod:`._arap_kernel`: no ``(N, 3G)``
matrix; spokes-and-rims pools per-triangle covariances ``S_v = Σ_{f∋v} S_f``), within a solve only for the groups it
can change (those holding an edge of an element with a free vertex). The derivation and the solver's choices:
docs/method.md, "Surface editing: ARAP".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import _arap_kernel as _kernel
from nerfedit_plugin.geometry.cholesky import SparseCholesky
from nerfedit_plugin.geometry.cotangent import ELEMENT_EDGES, cotangent_weights, edge_laplacian, incidence
from nerfedit_plugin.geometry.launch import launch
from nerfedit_plugin.geometry.soft_constraints import Expansion, SoftConstraints

ENERGIES = ("spokes_and_rims", "spokes", "elements")

#: Anderson acceleration history length (Peng et al. use 5–6 for ARAP)
ANDERSON_DEPTH = 5
#: relative energy (E / rest energy) below which E is summed term by term instead of by the cancelling quadratic form
RESIDUAL_BELOW = 1e-8
#: iterations over which the relative energy decrease is averaged for the stopping test
CONVERGENCE_WINDOW = 3
#: minimisation methods of :meth:`ArapSolver.solve`
METHODS = ("anderson", "lbfgs")
#: L-BFGS history length, backtracking halvings before the plain step, Armijo sufficient-decrease constant
LBFGS_DEPTH, LINE_SEARCH_STEPS, ARMIJO = 8, 4, 1e-4


class ArapResult(NamedTuple):
    """``vertices (N,3) float64``; ``iterations`` done; ``energies[k]`` = E (ARAP plus constraint penalty) after k
    iterations (``energies[0]`` at the start; non-increasing); ``converged`` = the relative decrease fell below the
    tolerance."""

    vertices: np.ndarray
    iterations: int
    energies: list[float]
    converged: bool


def fit_rotations(stacked: np.ndarray) -> np.ndarray:
    """stacked (3G,3) float64 → (3G,3) float64: the rotations maximising ``tr(R_g S_g)`` for ``G`` covariances
    stacked ``(3G, 3)`` (row ``a·G + g`` = row a of ``S_g``), returned as the ``R_gᵀ`` stacked the same way.

    Horn's quaternion method, compiled per group (:func:`_rotations`): R_g is the unit quaternion of the largest
    eigenvalue λ of the traceless symmetric 4×4 matrix N(S_g) (always a proper rotation, rank-deficient S included).
    λ is the largest root of ``det(N − λI) = λ⁴ − 2‖S‖²λ² − 8 det(S) λ + det N`` (S scaled to ``‖S‖_F = 1``), found
    by Laguerre's method from the upper bound ``√3`` (monotone, cubic convergence for real-rooted polynomials); the
    eigenvector is the largest column of ``adj(N − λI)``. Groups whose top eigenvalue is nearly double (rotation
    ill-determined) use :func:`fit_rotations_numpy`; empty groups get the identity.
    """
    g = len(stacked) // 3
    rotations = _rotations(np.ascontiguousarray(np.asarray(stacked, dtype=np.float64).reshape(3, g, 3).swapaxes(0, 1)))
    return np.ascontiguousarray(rotations.transpose(2, 0, 1)).reshape(3 * g, 3)


def _rotations(covariances: np.ndarray, rotations: np.ndarray | None = None) -> np.ndarray:
    """covariances (G,3,3) ``S_g`` → (G,3,3) ``R_g`` maximising ``tr(R_g S_g)`` (:func:`fit_rotations`), into
    ``rotations`` if given."""
    rotations = np.empty_like(covariances) if rotations is None else rotations
    ill = np.empty(len(covariances), dtype=bool)
    launch(_kernel.fit_rotations, covariances, rotations, ill)
    _refit_ill(covariances, rotations, np.flatnonzero(ill))
    return rotations


def _refit_ill(covariances: np.ndarray, rotations: np.ndarray, ill: np.ndarray) -> None:
    """Replace the rotations of the groups ``ill`` (indices) by :func:`fit_rotations_numpy`'s (SVD)."""
    if len(ill):
        stacked = covariances[ill].transpose(1, 0, 2).reshape(-1, 3)
        rotations[ill] = fit_rotations_numpy(stacked).reshape(3, -1, 3).transpose(1, 2, 0)


def fit_rotations_numpy(stacked: np.ndarray) -> np.ndarray:
    """:func:`fit_rotations` by batched SVD (same stacked ``(3G,3)`` float64 in and out): ``S = UΣVᵀ``,
    ``R = V diag(1, 1, det(VUᵀ)) Uᵀ``."""
    g = len(stacked) // 3
    u, _, vt = np.linalg.svd(stacked.reshape(3, g, 3).transpose(1, 0, 2))
    v = vt.transpose(0, 2, 1).copy()
    v[:, :, 2] *= np.sign(np.linalg.det(v @ u.transpose(0, 2, 1)))[:, None]
    rotations = v @ u.transpose(0, 2, 1)
    return np.ascontiguousarray(rotations.transpose(2, 0, 1).reshape(3 * g, 3))


class _Anderson:
    """Anderson acceleration (type II) of a fixed-point map x ↦ G(x) from its last ``depth`` evaluations.

    ``θ = argmin ‖f − ΔF θ‖`` (normal equations of the small Gram matrix ``ΔFᵀΔF``, updated a column at a time),
    next iterate ``G(x) − ΔG θ``.
    """

    def __init__(self, depth: int, size: int) -> None:
        self.d_g, self.d_f = np.empty((depth, size)), np.empty((depth, size))
        self.gram = np.zeros((depth, depth))
        self.last_g, self.last_f = np.empty(size), np.empty(size)
        self.count, self.started = 0, False
        self.extrapolated = False  # whether the last call extrapolated (else it returned g)

    def __call__(self, g: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Given ``g = G(x)`` and ``f = g − x`` (flat), the accelerated next iterate."""
        if self.started and len(self.d_g):
            slot = self.count % len(self.d_g)
            np.subtract(g, self.last_g, out=self.d_g[slot])
            np.subtract(f, self.last_f, out=self.d_f[slot])
            self.count += 1
            filled = min(self.count, len(self.d_g))
            self.gram[slot, :filled] = self.gram[:filled, slot] = np.einsum(
                "ai,i->a", self.d_f[:filled], self.d_f[slot]
            )
        self.last_g[:], self.last_f[:], self.started = g, f, True
        m = min(self.count, len(self.d_g))
        self.extrapolated = m > 0
        if not self.extrapolated:  # also when depth == 0
            return g
        theta = np.linalg.lstsq(self.gram[:m, :m], np.einsum("ai,i->a", self.d_f[:m], f), rcond=1e-12)[0]
        return g - np.einsum("a,ai->i", theta, self.d_g[:m])  # einsum: BLAS threads cost more than they save here


class _Lbfgs:
    """L-BFGS two-loop recursion on a quadratic-plus-rotations energy whose system matrix ``A`` is prefactored
    (Liu, Bouaziz & Kavan 2017), with initial inverse Hessian ``γ A⁻¹``, ``γ = sᵀy / yᵀA⁻¹y`` of the newest pair.

    Besides the steps ``s`` and gradient changes ``y`` it keeps ``z = A⁻¹y`` (the change of ``A⁻¹h``, which the
    caller computes anyway for the plain local/global step), so ``A⁻¹q = A⁻¹h − Σ α z`` and ``γ`` cost no
    back-substitution. Vectors are ``(n, 3)``, kept flat; each loop of the recursion makes one compiled pass per
    pair (the update of one pair fused with the dot product of the next), ``A⁻¹q`` one pass in all.
    """

    def __init__(self, depth: int, shape: tuple[int, int]) -> None:
        self.shape, size = shape, shape[0] * shape[1]
        self.s, self.y, self.z = (np.empty((depth, size)) for _ in range(3))
        self.rho = np.empty(depth)
        self.count = 0  # pairs pushed since the last reset (the newest min(count, depth) are kept)

    def reset(self) -> None:
        self.count = 0

    def push(
        self, x: tuple[np.ndarray, np.ndarray], h: tuple[np.ndarray, np.ndarray], p: tuple[np.ndarray, np.ndarray]
    ) -> None:
        """Add the pair ``s = x⁺ − x``, ``y = h⁺ − h`` (and ``z = A⁻¹y = p⁺ − p``), each given as ``(new, old)``,
        unless its curvature ``sᵀy`` is not clearly positive (E is not convex: such a pair would make the inverse
        Hessian indefinite)."""
        (x1, x0), (h1, h0), (p1, p0) = ((a.reshape(-1), b.reshape(-1)) for a, b in (x, h, p))
        curvature, ss, yy = launch(_kernel.difference_dots, x1, x0, h1, h0)
        if not curvature > 1e-12 * np.sqrt(ss * yy):
            return
        slot = self.count % len(self.rho)
        np.subtract(x1, x0, out=self.s[slot])
        np.subtract(h1, h0, out=self.y[slot])
        np.subtract(p1, p0, out=self.z[slot])
        self.rho[slot] = 1.0 / curvature
        self.count += 1

    def direction(self, h: np.ndarray, solved: np.ndarray) -> np.ndarray:
        """``H h`` for the half gradient ``h`` and ``solved = A⁻¹h`` (returned as is, a copy, without history)."""
        m = min(self.count, len(self.rho))
        if not m:
            return solved.copy()
        slots = np.array([(self.count - 1 - k) % len(self.rho) for k in range(m)])  # newest first
        alphas, rho, s, y = np.empty(m), self.rho, self.s, self.y
        q = h.reshape(-1).copy()
        alphas[0] = rho[slots[0]] * _dot(s[slots[0]], q)
        for k in range(m - 1):  # q ← q − α_k y_k, α_{k+1} = ρ s_{k+1}ᵀq
            alphas[k + 1] = rho[slots[k + 1]] * launch(_kernel.axpy_dot, q, alphas[k], y[slots[k]], s[slots[k + 1]])
        gamma = 1.0 / (rho[slots[0]] * _dot(y[slots[0]], self.z[slots[0]]))  # γ = sᵀy / yᵀA⁻¹y
        r = np.empty_like(q)
        launch(_kernel.combine, solved.reshape(-1), gamma, alphas, self.z, slots, r)  # r = γ A⁻¹q
        beta = rho[slots[-1]] * _dot(y[slots[-1]], r)
        for k in reversed(range(m)):  # r ← r + (α_k − β_k) s_k, β_{k−1} = ρ y_{k−1}ᵀr (the last dot unused)
            dot = launch(_kernel.axpy_dot, r, beta - alphas[k], s[slots[k]], y[slots[max(k - 1, 0)]])
            beta = rho[slots[k - 1]] * dot
        return r.reshape(self.shape)


def _finite(name: str, value: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as float64 when it has ``shape`` and only finite entries, else a NerfEditError saying which."""
    value = np.asarray(value, dtype=np.float64)
    if value.shape != shape:
        raise NerfEditError(f"ARAP: {name} must have shape {shape}, got {value.shape}")
    if not np.isfinite(value).all():
        bad = np.count_nonzero(~np.isfinite(value))
        raise NerfEditError(f"ARAP: {name} holds {bad} non-finite values (NaN or inf)")
    return value


class ArapSolver:
    """ARAP (Sorkine & Alexa 2007) on a triangle or tet mesh: cotangent weights, local polar step, global step
    with a prefactored sparse Cholesky; handle vertices eliminated exactly; optional soft linear constraints.

    ``vertices (N,3) float64`` (rest), ``elements (F,3)`` triangles or ``(K,4)`` tets int64, ``fixed (H,) int64``
    handle vertex indices, ``constraints`` a sparse ``C (m,N)`` (or a SoftConstraints holding it, sharing its
    ``CᵀC``).

    ``constraints`` ``C (m, N)`` and ``constraint_weight`` w add ``w_c ‖C X − T‖²`` with the dimensionless ``w``
    scaled to ``w_c = w · mean(diag(m·L))`` (the average stiffness of a vertex in the ARAP system), so ``w = 1``
    weighs a constraint like one vertex's neighbourhood and ``w ≫ 1`` approaches interpolation. Everything is
    factored here; each :meth:`solve` is back-substitutions only. Vertices referenced by no element keep their
    ``initial`` position. Raises :class:`NerfEditError` if a connected component has no fixed vertex and no
    constraint (its position would be undetermined).
    """

    def __init__(
        self,
        vertices: np.ndarray,
        elements: np.ndarray,
        *,
        energy: str | None = None,
        fixed: np.ndarray | tuple = (),
        constraints: sp.spmatrix | SoftConstraints | None = None,
        constraint_weight: float = 0.0,
    ) -> None:
        rest = np.asarray(vertices, dtype=np.float64)
        elements = np.asarray(elements, dtype=np.int64)
        if rest.ndim != 2 or rest.shape[1] != 3 or not np.isfinite(rest).all():
            raise NerfEditError(f"ARAP: vertices must be a finite (N,3) array, got shape {rest.shape}")
        if elements.ndim != 2 or elements.shape[1] not in ELEMENT_EDGES or len(elements) == 0:
            raise NerfEditError(f"ARAP: elements must be triangles (F,3) or tets (K,4), got shape {elements.shape}")
        n = len(rest)
        if elements.min() < 0 or elements.max() >= n:
            raise NerfEditError(f"ARAP: element vertex index out of range for {n} vertices")
        energy = energy or ("spokes_and_rims" if elements.shape[1] == 3 else "elements")
        if energy not in ENERGIES:
            raise NerfEditError(f"ARAP: unknown energy {energy!r} (expected one of {list(ENERGIES)})")
        fixed = np.asarray(fixed, dtype=np.int64).ravel()
        if fixed.size and (fixed.min() < 0 or fixed.max() >= n):
            raise NerfEditError(f"ARAP: fixed vertex index out of range for {n} vertices")
        if len(np.unique(fixed)) != len(fixed):
            raise NerfEditError("ARAP: fixed vertex indices repeat")
        if constraints is not None:
            soft = constraints if isinstance(constraints, SoftConstraints) else SoftConstraints(constraints)
            constraints = soft.matrix
            if constraints.shape[1] != n:
                raise NerfEditError(f"ARAP: constraints have {constraints.shape[1]} columns, expected {n}")
            if not (np.isfinite(constraint_weight) and constraint_weight > 0):
                raise NerfEditError(f"ARAP: constraint_weight must be > 0 with constraints, got {constraint_weight}")
        self.n_vertices, self.energy_type, self.fixed = n, energy, fixed
        self._rest_fixed = rest[fixed]
        self.origin = rest.mean(0)  # work in centred coordinates: the energy is a difference of large terms
        self.rest = rest - self.origin

        corners = elements.shape[1]
        pairs = ELEMENT_EDGES[corners]
        weights = cotangent_weights(rest, elements)
        self._vertex_start, self._vertex_corners = incidence(elements, n)
        lap = edge_laplacian(elements, weights, n, (self._vertex_start, self._vertex_corners))
        self._check_components(lap, constraints)
        self._mode = _kernel.MODES[energy]
        multiplicity = {"elements": 1, "spokes_and_rims": corners, "spokes": 2}[energy]
        self._elements, self._pairs, self._weights = elements, pairs, weights
        self._wedges = np.empty((len(elements), len(pairs), 3))  # u = w (p_i − p_j)
        launch(_kernel.weighted_edges, self.rest, elements, pairs, weights, self._wedges)
        self._buffers = None
        self._per_corner = energy == "spokes"  # covariance pieces: per corner, else per element
        if energy == "elements":
            self.n_groups = len(elements)
            self._group_start, self._group_pieces = np.arange(len(elements) + 1), np.arange(len(elements))
        else:
            self.n_groups = n
            pieces = self._vertex_corners if self._per_corner else self._vertex_corners // corners
            self._group_start, self._group_pieces = self._vertex_start, pieces
        lap.data *= multiplicity
        self._laplacian = lap
        system = self._laplacian
        self.constraints, self.constraint_weight = constraints, 0.0
        if constraints is not None:
            referenced = np.diff(lap.indptr) > 0
            self.constraint_weight = float(constraint_weight) * float(self._laplacian.diagonal()[referenced].mean())
            self._soft = soft
            system = (system + self.constraint_weight * soft.gram).tocsr()
        self._rest_energy = float(np.sum(self.rest * (self._laplacian @ self.rest)))

        is_free = np.zeros(n, dtype=bool)
        is_free[elements.ravel()] = True
        is_free[fixed] = False
        self.free = np.flatnonzero(is_free)
        self.known = np.flatnonzero(~is_free)  # fixed and unreferenced vertices
        rows = system[self.free]
        stiffness = system.diagonal()[self.free]
        if len(self.free) and stiffness.min() <= 0:
            vertex = int(self.free[np.argmin(stiffness)])
            raise NerfEditError(
                f"ARAP: vertex {vertex} has no stiffness: all its elements are degenerate (zero area or volume)"
            )
        # what a solve can change: the elements with a free vertex (their edges move), the groups holding those
        # edges, and the elements whose covariance pieces these groups pool; other groups keep their rotations
        moving = np.flatnonzero(is_free[elements].any(1))
        if energy == "elements":
            groups, pieced = moving, moving
        else:
            held = np.zeros(n, dtype=bool)
            held[elements[moving]] = True
            groups, pieced = np.flatnonzero(held), np.flatnonzero(held[elements].any(1))
        self._moving, self._active = moving, (pieced, groups)
        self._everything = (np.arange(len(elements)), np.arange(self.n_groups))
        self._system_known = rows[:, self.known].tocsr()
        self._system_free = rows[:, self.free].tocsr()
        self._factor = SparseCholesky(self._system_free) if len(self.free) else None

    # ---- set-up helpers ------------------------------------------------------------------------
    def _check_components(self, laplacian: sp.csr_matrix, constraints: sp.csr_matrix | None) -> None:
        """Raise unless every connected part of the element graph (``laplacian``'s pattern) has a fixed vertex or a
        constraint."""
        n = self.n_vertices
        graph = sp.csr_matrix((np.ones(laplacian.nnz), laplacian.indices, laplacian.indptr), shape=(n, n))
        n_comp, labels = connected_components(graph, directed=False)
        anchored = np.zeros(n_comp, dtype=bool)
        anchored[labels[self.fixed]] = True
        if constraints is not None:
            indicator = sp.csr_matrix((np.ones(n), (np.arange(n), labels)), shape=(n, n_comp))
            anchored |= np.asarray((constraints @ indicator).power(2).sum(0)).ravel() > 0
        referenced = np.diff(laplacian.indptr) > 0
        loose = referenced & ~anchored[labels]
        if loose.any():
            vertex = int(np.flatnonzero(loose)[0])
            size = int(np.count_nonzero(labels == labels[vertex]))
            what = "no fixed vertex and no constraint" if constraints is not None else "no fixed vertex (handle)"
            raise NerfEditError(
                f"ARAP: a connected component of {size} of the {n} vertices (containing vertex {vertex}) has {what}, "
                "so its position is undetermined: give every connected part at least one handle"
            )

    # ---- iteration pieces ----------------------------------------------------------------------
    def _local(self, x: np.ndarray, penalty: Expansion | None, active: bool = False) -> tuple[np.ndarray, float]:
        """Best rotations ``R_g (G,3,3)`` for centred positions ``x`` and the energy ``E(x)`` with them (plus
        ``w_c ‖C x − T‖²`` from ``penalty``, the solve's constraint targets, if any).

        ``active``: refit only the groups a solve can change (holding an edge of an element with a free vertex);
        the others keep the traces ``tr(R_g S_g)`` of the last full call, which must have had the same fixed
        positions, and their rotations are left unset. ``E = tr(XᵀmLX) − 2 Σ_g tr(R_g S_g) + tr(PᵀmLP)`` costs one
        sparse product but loses digits to cancellation when E ≪ tr(PᵀmLP) (near-rigid results); there the
        residuals are summed term by term.
        """
        pieces, covariances, traces, ill, _ = self._scratch()
        pieced, groups = self._active if active else self._everything
        rotations = np.empty((self.n_groups, 3, 3))
        launch(
            _kernel.piece_covariances, x, self._elements, self._pairs, self._wedges, self._per_corner, pieced, pieces
        )
        launch(
            _kernel.local_step, pieces, self._group_start, self._group_pieces, groups, covariances, rotations, traces,
            ill,
        )  # fmt: skip
        flagged = groups[ill[groups]]
        if len(flagged):
            _refit_ill(covariances, rotations, flagged)
            traces[flagged] = np.einsum("gca,gac->g", rotations[flagged], covariances[flagged])
        value = float(np.sum(x * (self._laplacian @ x))) - 2.0 * float(np.sum(traces)) + self._rest_energy
        if abs(value) < RESIDUAL_BELOW * self._rest_energy:  # few digits left after cancellation: sum the residuals
            if active:  # the sum needs every rotation
                return self._local(x, penalty)
            terms = np.empty(len(self._elements))  # rare: not kept
            launch(
                _kernel.residual_energy, x, self.rest, self._elements, self._pairs, self._weights, rotations,
                self._mode, terms,
            )  # fmt: skip
            value = float(np.sum(terms))
        if penalty is not None:
            value += self.constraint_weight * penalty.value(x)
        return rotations, value

    def _scratch(self) -> tuple[np.ndarray, ...]:
        """Work arrays of the kernels, allocated once: covariance pieces, covariances (G,3,3), traces (G,), ill (G,),
        turned edges (F,E,3)."""
        if self._buffers is None:
            g, count = self.n_groups, self._elements.size if self._per_corner else len(self._elements)
            self._buffers = (
                np.empty((count, 3, 3)), np.empty((g, 3, 3)), np.empty(g), np.empty(g, dtype=bool),
                np.empty_like(self._wedges),
            )  # fmt: skip
        return self._buffers

    def _rotated_edges(self, rotations: np.ndarray) -> np.ndarray:
        """``(K R)`` (free rows, 3): the global step's right-hand side ``Σ ±R_g w (p_i − p_j)`` at each free vertex
        (reads the rotations of the groups :meth:`_local` refits with ``active``)."""
        turned, out = self._scratch()[4], np.empty((len(self.free), 3))
        launch(
            _kernel.rotate_edges, self._elements, self._pairs, self._wedges, rotations, self._mode, self._moving, turned
        )
        launch(
            _kernel.gather_edges, self._elements, self._pairs, turned, self.free, self._vertex_start,
            self._vertex_corners, out,
        )  # fmt: skip
        return out

    def _penalty(self, x: np.ndarray, targets: np.ndarray | None) -> Expansion | None:
        """The constraint penalty for ``targets (m,3)`` (default ``C·rest``) expanded about the centred positions
        ``x`` (N,3); None without constraints."""
        if self.constraints is None:
            return None
        if targets is None:
            return self._soft.expand(x, self.constraints @ self.rest)  # centred rest, centred targets
        targets = _finite("constraint_targets", targets, (self.constraints.shape[0], 3))
        return self._soft.expand(x, targets, self.origin)

    # ---- public API ------------------------------------------------------------------------------
    def energy(self, positions: np.ndarray, constraint_targets: np.ndarray | None = None) -> float:
        """positions (N,3) float64, constraint_targets (m,3) float64 or None → float: ``E(X)`` with the optimal
        rotations, plus ``w_c ‖C X − T‖²`` when there are constraints (``T`` defaults to ``C·rest``)."""
        x = np.asarray(positions, dtype=np.float64) - self.origin
        return self._local(x, self._penalty(x, constraint_targets))[1]

    def vertex_rotations(self, positions: np.ndarray) -> np.ndarray:
        """positions (N,3) float64 → (N,3,3) float64: per vertex ``v`` the rotation ``R_v`` maximising
        ``tr(R_v S_v)``, ``S_v`` the covariance of the edges of the elements at ``v`` (the spokes-and-rims
        covariance; spokes: the edges at ``v``), so ``x_i − x_j ≈ R_v (p_i − p_j)`` around ``v``. The identity
        where ``v`` is in no element. With ``spokes_and_rims`` or ``spokes`` these are the local step's rotations."""
        x = _finite("positions", positions, self.rest.shape) - self.origin
        pieces = self._scratch()[0]
        launch(
            _kernel.piece_covariances, x, self._elements, self._pairs, self._wedges, self._per_corner,
            self._everything[0], pieces,
        )  # fmt: skip
        corners = self._elements.shape[1]
        owners = self._vertex_corners if self._per_corner else self._vertex_corners // corners
        n = self.n_vertices
        covariances, rotations = np.empty((n, 3, 3)), np.empty((n, 3, 3))
        traces, ill = np.empty(n), np.empty(n, dtype=bool)
        launch(
            _kernel.local_step, pieces, self._vertex_start, owners, np.arange(n), covariances, rotations, traces, ill
        )
        _refit_ill(covariances, rotations, np.flatnonzero(ill))
        rotations[np.diff(self._vertex_start) == 0] = np.eye(3)
        return rotations

    def solve(
        self,
        fixed_positions: np.ndarray | None = None,
        constraint_targets: np.ndarray | None = None,
        initial: np.ndarray | None = None,
        *,
        max_iterations: int = 200,
        tolerance: float = 1e-6,
        method: str = "anderson",
        anderson: int = ANDERSON_DEPTH,
        callback: Callable[[int, float], None] | None = None,
    ) -> ArapResult:
        """Minimise E with the fixed vertices at ``fixed_positions (H,3)`` (default: rest) and constraint targets
        ``constraint_targets (m,3)`` (default: ``C·rest``), starting from ``initial (N,3)`` (default: rest), whose
        fixed rows are replaced; all float64 → :class:`ArapResult` (``vertices (N,3) float64``). Stops when the
        relative energy decrease per iteration, averaged over the last :data:`CONVERGENCE_WINDOW` iterations
        (accelerated steps progress unevenly), is ≤ ``tolerance``, or after ``max_iterations``.

        ``method``: ``"anderson"``, local/global iterations Anderson-accelerated with history ``anderson`` (0: plain
        iterations, whose iterates are libigl's ``arap_solve`` iterates); ``"lbfgs"``, L-BFGS on E (Liu, Bouaziz &
        Kavan 2017; history :data:`LBFGS_DEPTH`, initial inverse Hessian ``γ A⁻¹``, Armijo backtracking, the plain
        local/global step when that fails). Both keep E non-increasing and cost one back-substitution per
        iteration; L-BFGS needs far fewer iterations on large meshes (docs/benchmarks.md, "Edits at scale").

        ``callback(k, energies[k])``, if given, is called as each energy of :attr:`ArapResult.energies` is known
        (k = 0 at the start, then once per iteration); it must not change the solve's arrays."""
        if method not in METHODS:
            raise NerfEditError(f"ARAP: unknown method {method!r} (expected one of {list(METHODS)})")
        x = self.rest.copy() if initial is None else _finite("initial", initial, self.rest.shape) - self.origin
        if fixed_positions is not None:
            fixed_positions = _finite("fixed_positions", fixed_positions, (len(self.fixed), 3))
        else:
            fixed_positions = self._rest_fixed
        x[self.fixed] = fixed_positions - self.origin
        penalty = self._penalty(x, constraint_targets)
        rhs = -(self._system_known @ x[self.known])
        if penalty is not None:
            rhs += self.constraint_weight * penalty.pulled_targets[self.free]

        rotations, energy = self._local(x, penalty)
        energies = [energy]
        if callback is not None:
            callback(0, energy)
        floor = 1e-20 * max(self._rest_energy, np.finfo(float).tiny)
        if self._factor is not None and abs(energy) > floor:
            iterate = self._lbfgs if method == "lbfgs" else self._anderson
            x, converged = iterate(
                x, rotations, rhs, penalty, energies, max_iterations, tolerance, floor, anderson, callback
            )
        else:
            converged = True
        vertices = x + self.origin
        vertices[self.fixed] = fixed_positions  # exactly, without the round trip through centred coordinates
        return ArapResult(vertices, len(energies) - 1, energies, bool(converged))

    # ---- minimisers: from centred x (fixed rows set) and its rotations, append to energies (calling callback, if
    # any, with each), return (x, converged)
    def _anderson(self, x, rotations, rhs, penalty, energies, max_iterations, tolerance, floor, depth, callback):
        """Local/global iterations Anderson-accelerated (history ``depth``) under the energy guard."""
        energy, converged = energies[-1], False
        accelerator = _Anderson(depth, 3 * len(self.free))
        while not converged and len(energies) <= max_iterations:
            plain = self._factor.solve(self._rotated_edges(rotations) + rhs)
            trial = x.copy()
            trial[self.free] = accelerator(plain.ravel(), (plain - x[self.free]).ravel()).reshape(-1, 3)
            trial_rotations, trial_energy = self._local(trial, penalty, active=True)
            if accelerator.extrapolated and not trial_energy < energy:  # no gain: take the plain local/global iterate
                trial[self.free] = plain
                trial_rotations, trial_energy = self._local(trial, penalty, active=True)
            if trial_energy > energy:  # only rounding makes a plain step increase E: we are at the minimum
                return x, True
            x, rotations, energy = trial, trial_rotations, trial_energy
            energies.append(energy)
            if callback is not None:
                callback(len(energies) - 1, energy)
            converged = _converged(energies, tolerance, floor)
        return x, converged

    def _lbfgs(self, x, rotations, rhs, penalty, energies, max_iterations, tolerance, floor, _depth, callback):
        """L-BFGS on E over the free vertices. The half gradient ``h = A x − (K R(x) + b)`` (R(x): the local
        step's rotations, optimal, so the rotations' own variation drops out) and ``p = A⁻¹h`` give the plain
        local/global iterate ``x − p``; the L-BFGS step ``x − α H h`` is tried at α = 1, ½, ¼, ⅛ (Armijo), else
        the plain step is taken and the history cleared, so E never increases."""
        free, energy = self.free, energies[-1]
        history = _Lbfgs(LBFGS_DEPTH, (len(free), 3))
        xf = x[free]
        h = self._system_free @ xf - self._rotated_edges(rotations) - rhs
        p = self._factor.solve(h)
        while len(energies) <= max_iterations:
            r = history.direction(h, p)
            slope = _dot(h, r)  # −½ dE/dα along −r
            if history.count and not slope > 0:  # not a descent direction: start over from the plain step
                history.reset()
                r, slope = p, _dot(h, p)
            trial = x.copy()
            for attempt in range(LINE_SEARCH_STEPS if history.count else 1):
                alpha = 0.5**attempt
                trial[free] = xf - alpha * r
                trial_rotations, trial_energy = self._local(trial, penalty, active=True)
                if trial_energy <= energy - 2.0 * ARMIJO * alpha * slope:
                    break
            else:
                if history.count:  # the plain local/global step
                    history.reset()
                    trial[free] = xf - p
                    trial_rotations, trial_energy = self._local(trial, penalty, active=True)
            if trial_energy > energy:  # only rounding makes a plain step increase E: we are at the minimum
                return x, True
            new_xf = trial[free]
            new_h = self._system_free @ new_xf - self._rotated_edges(trial_rotations) - rhs
            new_p = self._factor.solve(new_h)
            history.push((new_xf, xf), (new_h, h), (new_p, p))  # A⁻¹(h⁺ − h) = p⁺ − p: no back-substitution
            x, xf, h, p, energy = trial, new_xf, new_h, new_p, trial_energy
            energies.append(energy)
            if callback is not None:
                callback(len(energies) - 1, energy)
            if _converged(energies, tolerance, floor):
                return x, True
        return x, False


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """``Σ a ⊙ b`` of two contiguous arrays of one shape (einsum: BLAS ``ddot`` spends its time in thread start-up at
    these sizes)."""
    return float(np.einsum("i,i->", a.reshape(-1), b.reshape(-1)))


def _converged(energies: list[float], tolerance: float, floor: float) -> bool:
    """The relative energy decrease per iteration over the last :data:`CONVERGENCE_WINDOW` iterations is ≤
    ``tolerance``, or E is below ``floor``."""
    window = min(CONVERGENCE_WINDOW, len(energies) - 1)
    before = energies[-1 - window]
    return before - energies[-1] <= window * tolerance * abs(before) or abs(energies[-1]) <= floor
