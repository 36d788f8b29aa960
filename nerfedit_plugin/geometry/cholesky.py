"""Sparse symmetric positive definite factorisations, factored once and solved for many right-hand sides: cholespy
(CHOLMOD) when installed, else scipy's SuperLU. Shared by the ARAP solver, the injective lift and deformation
transfer."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from nerfedit_plugin.errors import NerfEditError


class SparseCholesky:
    """``SparseCholesky(A)`` factors the sparse SPD matrix ``A`` (n,n) once (SuperLU is 2–3× slower than CHOLMOD);
    ``solve(b)``: ``A⁻¹ b`` for ``b`` (n,) or (n,k) float64. A matrix CHOLMOD finds indefinite is a NerfEditError."""

    def __init__(self, matrix: sp.csr_matrix) -> None:
        matrix = matrix.tocsr()
        matrix.sort_indices()
        try:
            from cholespy import CholeskySolverD, MatrixType
        except ImportError:
            from scipy.sparse.linalg import splu

            self._cholesky, self._lu = None, splu(matrix.tocsc(), permc_spec="COLAMD")
            return
        try:
            self._cholesky = CholeskySolverD(
                matrix.shape[0],
                matrix.indptr.astype(np.int32),
                matrix.indices.astype(np.int32),
                np.ascontiguousarray(matrix.data),
                MatrixType.CSR,
            )
        except ValueError as exc:
            raise NerfEditError(f"sparse Cholesky: the matrix is not positive definite ({exc})") from exc

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        rhs = np.ascontiguousarray(rhs, dtype=np.float64)
        if self._cholesky is None:
            return self._lu.solve(rhs)
        out = np.empty_like(rhs)
        self._cholesky.solve(rhs, out)
        return out
