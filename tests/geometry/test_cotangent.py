"""Cotangent weights and the Laplacian they assemble: libigl's ``cotmatrix``, and a coo assembly as the oracle of the
compiled CSR one (pattern, zeros, empty rows)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from nerfedit_plugin.geometry.cotangent import ELEMENT_EDGES, cotangent_weights, edge_laplacian
from tests.geometry.test_arap import sample_mesh, tet_grid

igl = pytest.importorskip("igl")


def coo_laplacian(elements: np.ndarray, weights: np.ndarray, n: int) -> sp.csr_matrix:
    """``Σ w (e_i − e_j)(e_i − e_j)ᵀ`` by coo assembly (duplicates summed, zeros kept)."""
    pairs = ELEMENT_EDGES[elements.shape[1]]
    i, j, w = elements[:, pairs[:, 0]].ravel(), elements[:, pairs[:, 1]].ravel(), weights.ravel()
    rows, cols = np.concatenate([i, j, i, j]), np.concatenate([j, i, i, j])
    return sp.coo_matrix((np.concatenate([-w, -w, w, w]), (rows, cols)), shape=(n, n)).tocsr()


@pytest.mark.parametrize("mesh", ["cow", "tets"])
def test_laplacian_is_libigl_cotmatrix_and_the_coo_assembly(mesh):
    vertices, elements = sample_mesh("cow.obj") if mesh == "cow" else tet_grid()
    weights = cotangent_weights(vertices, elements)
    laplacian = edge_laplacian(elements, weights, len(vertices))
    reference = -igl.cotmatrix(vertices, elements)
    assert abs(laplacian - reference).max() <= 1e-12 * abs(reference).max()
    oracle = coo_laplacian(elements, weights, len(vertices))
    oracle.sort_indices()
    assert laplacian.has_sorted_indices
    assert np.array_equal(laplacian.indptr, oracle.indptr) and np.array_equal(laplacian.indices, oracle.indices)
    assert np.abs(laplacian.data - oracle.data).max() <= 1e-12 * np.abs(oracle.data).max()


def test_degenerate_elements_weigh_zero_and_unreferenced_rows_stay_empty():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 5, 5]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 1, 3]])  # the second is flat: three collinear vertices
    weights = cotangent_weights(vertices, faces)
    assert np.array_equal(weights[1], np.zeros(3))
    assert weights[0] == pytest.approx([0.0, 0.5, 0.5])  # ½ cot 90°, ½ cot 45° twice
    laplacian = edge_laplacian(faces, weights, len(vertices))
    assert np.diff(laplacian.indptr).tolist() == [4, 4, 3, 3, 0]  # vertex 4 is in no face
    row = slice(laplacian.indptr[1], laplacian.indptr[2])
    assert laplacian.indices[row].tolist() == [0, 1, 2, 3] and laplacian.data[row][3] == 0.0  # the flat face's edge
    assert np.abs(laplacian.sum(axis=1)).max() <= 1e-15
