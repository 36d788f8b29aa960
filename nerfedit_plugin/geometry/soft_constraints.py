"""Soft linear constraints ``‖C X − T‖²`` (``C (m,N)`` sparse, ``X (N,3)``, ``T (m,3)``) evaluated in the size of
the unknowns, not of the constraints.

A lift embeds every surface vertex in the proxy (``m`` of them, millions at the resolutions users extract) against a
few thousand proxy vertices ``N``; a solver evaluates the penalty and its gradient many times per target set. With
``G = CᵀC`` (once per ``C``) and, once per target set, a base point ``X₀`` (the solve's start) and ``r₀ = T − C X₀``,

``‖C X − T‖² = tr(Dᵀ G D) − 2 tr(Dᵀ Cᵀr₀) + ‖r₀‖²``,  ``Cᵀ(C X − T) = G D − Cᵀr₀``,  ``D = X − X₀``,

an identity, so every later call costs ``O(nnz G)`` instead of ``O(nnz C)``; ``r₀``'s one pass over the rows is
compiled (:func:`_pull`: no ``(m,3)`` temporaries). Rounding is relative to ``‖r₀‖²`` (the base's misfit, not the
targets' magnitude); where a value falls below :data:`REBASE_BELOW` × ``‖r₀‖²`` the expansion moves its base to that
point (one more pass over the rows), so a value keeps at least ``ε / REBASE_BELOW`` relative precision however far
the misfit falls. Solvers that centre their positions pass the centre as ``origin``: the targets stay as given,
``C (X + origin) − T``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from nerfedit_plugin.errors import NerfEditError

#: value / ‖r₀‖² below which the expansion moves its base to the point evaluated (digits lost to cancellation)
REBASE_BELOW = 1e-4


@njit(cache=True)
def _pull(indptr, indices, data, base, origin, targets, pulled):
    """``r = T − C (base + origin)`` row by row: ``pulled += Cᵀ r`` (N,3); returns ``‖r‖²``."""
    total = 0.0
    for row in range(len(indptr) - 1):
        r0, r1, r2 = targets[row, 0], targets[row, 1], targets[row, 2]
        for k in range(indptr[row], indptr[row + 1]):
            c, j = data[k], indices[k]
            r0 -= c * (base[j, 0] + origin[0])
            r1 -= c * (base[j, 1] + origin[1])
            r2 -= c * (base[j, 2] + origin[2])
        total += r0 * r0 + r1 * r1 + r2 * r2
        for k in range(indptr[row], indptr[row + 1]):
            c, j = data[k], indices[k]
            pulled[j, 0] += c * r0
            pulled[j, 1] += c * r1
            pulled[j, 2] += c * r2
    return total


class Expansion:
    """``‖C (X + origin) − T‖²`` and ``Cᵀ(C (X + origin) − T)`` for one target set ``T``, expanded about ``X₀``
    (module docstring; :meth:`value` may move ``X₀``, which changes no result beyond rounding). Wrong shapes of the
    targets (m,3), positions (N,3) or origin (3,) are a NerfEditError."""

    def __init__(self, constraints: SoftConstraints, base: np.ndarray, targets: np.ndarray, origin: np.ndarray) -> None:
        m, n = constraints.matrix.shape
        targets, base = np.ascontiguousarray(targets, dtype=np.float64), np.array(base, dtype=np.float64)
        origin = np.asarray(origin, dtype=np.float64)
        for name, array, shape in (("targets", targets, (m, 3)), ("positions", base, (n, 3)), ("origin", origin, (3,))):
            if array.shape != shape:
                raise NerfEditError(f"soft constraints: {name} must have shape {shape}, got {array.shape}")
        self._constraints, self._targets, self._origin = constraints, targets, origin
        self._rebase(base)

    def _rebase(self, base: np.ndarray) -> None:
        """Expand about ``base`` (N,3): ``Cᵀr₀`` and ``‖r₀‖²`` in one pass over the rows."""
        matrix = self._constraints.matrix
        self._base = np.array(base, dtype=np.float64)
        self._pulled = np.zeros_like(self._base)
        self._offset = _pull(
            matrix.indptr, matrix.indices, matrix.data, self._base, self._origin, self._targets, self._pulled
        )

    @property
    def pulled_targets(self) -> np.ndarray:
        """(N,3) float64 ``Cᵀ(T − C·origin)``: the targets pulled back to the unknowns, in their frame."""
        return self._constraints.gram @ self._base + self._pulled

    def value(self, x: np.ndarray) -> float:
        """x (N,3) float64 → ``‖C (x + origin) − T‖²`` (moving the base to x where the expansion lost its digits)."""
        d = x - self._base
        value = float(np.sum(d * (self._constraints.gram @ d))) - 2.0 * float(np.sum(d * self._pulled)) + self._offset
        if value < REBASE_BELOW * self._offset:
            self._rebase(x)
            return self._offset
        return value

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """x (N,3) float64 → (N,3) float64 ``Cᵀ(C (x + origin) − T)`` (half the gradient of the value)."""
        return self._constraints.gram @ (x - self._base) - self._pulled


class SoftConstraints:
    """A sparse ``C (m,N)`` and ``G = CᵀC`` (CSR, float64); :meth:`expand` binds a target set."""

    def __init__(self, matrix: sp.spmatrix) -> None:
        self.matrix = sp.csr_matrix(matrix, dtype=np.float64)
        self.gram = (self.matrix.T @ self.matrix).tocsr()

    def expand(self, base: np.ndarray, targets: np.ndarray, origin: np.ndarray | None = None) -> Expansion:
        """base (N,3) float64 (where the solve starts), targets (m,3) float64, origin (3,) float64 (default 0) of
        the positions' frame → the :class:`Expansion` about base."""
        return Expansion(self, base, targets, np.zeros(3) if origin is None else origin)
