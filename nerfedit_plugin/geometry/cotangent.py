"""Cotangent weights of triangle and tetrahedral meshes and the Laplacian ``L = Σ w (e_i − e_j)(e_i − e_j)ᵀ`` they
assemble (``−igl.cotmatrix``), in compiled kernels that make no per-element temporaries: at millions of elements
numpy's gathers and cross products spend more time faulting in fresh pages than computing.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit, prange

from nerfedit_plugin.geometry.launch import launch

#: local vertex pairs of the edges of a triangle (edge e is opposite corner e) and of a tetrahedron
ELEMENT_EDGES = {
    3: np.array([[1, 2], [2, 0], [0, 1]]),
    4: np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]),
}


def cotangent_weights(vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """vertices (N,3) float64, elements (F,3) triangles or (F,4) tets int64 → ``(F,E)`` float64 weights
    ``w_ij = −vol ∇φ_i·∇φ_j`` of the element edges :data:`ELEMENT_EDGES` (E = 3 or 6; 0 on degenerate elements:
    measure ≤ 1e-12 × the mean).

    Triangles: ½ cot of the opposite angle. Tets: ⅙ l cot θ (length and dihedral angle of the opposite edge).
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    elements = np.ascontiguousarray(elements, dtype=np.int64)
    pairs = ELEMENT_EDGES[elements.shape[1]]
    weights, measure = np.empty((len(elements), len(pairs))), np.empty(len(elements))
    launch(_element_weights, vertices, elements, pairs, weights, measure)
    threshold = 1e-12 * measure.mean() if len(measure) else 0.0
    launch(_divide, weights, measure, threshold)
    return weights


def edge_laplacian(
    elements: np.ndarray, weights: np.ndarray, n_vertices: int, corners: tuple[np.ndarray, np.ndarray] | None = None
) -> sp.csr_matrix:
    """elements (F,C) int64, weights (F,E) float64 (one per :data:`ELEMENT_EDGES` edge) → ``L (N,N)`` CSR float64,
    ``L = Σ_f Σ_e w_fe (e_i − e_j)(e_i − e_j)ᵀ``: an entry for every element edge and every referenced vertex's
    diagonal (zeros kept; rows of unreferenced vertices empty), sorted column indices. ``corners``: the elements'
    :func:`incidence`, if known."""
    elements = np.ascontiguousarray(elements, dtype=np.int64)
    pairs = ELEMENT_EDGES[elements.shape[1]]
    start, corners = incidence(elements, n_vertices) if corners is None else corners
    counts = np.empty(n_vertices, dtype=np.int64)
    launch(_row_counts, elements, start, corners, counts)
    indptr = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    indices, data = np.empty(indptr[-1], dtype=np.int64), np.empty(indptr[-1])
    launch(_rows, elements, pairs, np.ascontiguousarray(weights), start, corners, indptr, indices, data)
    return sp.csr_matrix((data, indices, indptr), shape=(n_vertices, n_vertices))


@njit(cache=True)
def incidence(elements, n_vertices):
    """elements (F,C) int64 → ``(start (N+1,), corners (F·C,))`` int64: the corners ``f·C + c`` at each vertex,
    ascending (a counting sort)."""
    flat = elements.ravel()
    start = np.zeros(n_vertices + 1, dtype=np.int64)
    for k in range(len(flat)):
        start[flat[k] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    corners = np.empty(len(flat), dtype=np.int64)
    for k in range(len(flat)):
        v = flat[k]
        corners[fill[v]] = k
        fill[v] += 1
    return start, corners


@njit(cache=True, parallel=True)
def _element_weights(x, elements, pairs, numerator, measure):
    """Per element: ``numerator[f, e]`` (the weight times ``measure[f]``: 2·area or 6·volume)."""
    for f in prange(len(elements)):
        if elements.shape[1] == 3:
            for e in range(3):
                o, i, j = elements[f, e], elements[f, pairs[e, 0]], elements[f, pairs[e, 1]]
                a0, a1, a2 = x[i, 0] - x[o, 0], x[i, 1] - x[o, 1], x[i, 2] - x[o, 2]
                b0, b1, b2 = x[j, 0] - x[o, 0], x[j, 1] - x[o, 1], x[j, 2] - x[o, 2]
                numerator[f, e] = 0.5 * (a0 * b0 + a1 * b1 + a2 * b2)
                if e == 0:
                    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
                    measure[f] = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        else:
            p = elements[f, 0]
            d = np.empty((3, 3))
            for k in range(3):
                for c in range(3):
                    d[k, c] = x[elements[f, k + 1], c] - x[p, c]
            n = np.empty((4, 3))  # det·∇φ_0..3
            for k in range(3):
                u, v = d[(k + 1) % 3], d[(k + 2) % 3]
                n[k + 1, 0], n[k + 1, 1], n[k + 1, 2] = (
                    u[1] * v[2] - u[2] * v[1],
                    u[2] * v[0] - u[0] * v[2],
                    u[0] * v[1] - u[1] * v[0],
                )
            for c in range(3):
                n[0, c] = -(n[1, c] + n[2, c] + n[3, c])
            for e in range(len(pairs)):
                a, b = pairs[e, 0], pairs[e, 1]
                numerator[f, e] = -(n[a, 0] * n[b, 0] + n[a, 1] * n[b, 1] + n[a, 2] * n[b, 2]) / 6.0
            measure[f] = abs(d[0, 0] * n[1, 0] + d[0, 1] * n[1, 1] + d[0, 2] * n[1, 2])


@njit(cache=True, parallel=True)
def _divide(weights, measure, threshold):
    """``weights[f] /= measure[f]`` where ``measure[f] > threshold``, else 0."""
    for f in prange(len(weights)):
        for e in range(weights.shape[1]):
            weights[f, e] = weights[f, e] / measure[f] if measure[f] > threshold else 0.0


@njit(cache=True)
def _neighbours(elements, start, corners, v, out):
    """The sorted distinct vertices sharing an element with ``v`` (``v`` included) into ``out``; returns their count
    (0 for a vertex in no element)."""
    n_corners, count = elements.shape[1], 0
    for k in range(start[v], start[v + 1]):
        f = corners[k] // n_corners
        for c in range(n_corners):
            out[count] = elements[f, c]
            count += 1
    if count == 0:
        return 0
    ordered = np.sort(out[:count])
    distinct = 1
    out[0] = ordered[0]
    for k in range(1, count):
        if ordered[k] != out[distinct - 1]:
            out[distinct] = ordered[k]
            distinct += 1
    return distinct


@njit(cache=True, parallel=True)
def _row_counts(elements, start, corners, counts):
    for v in prange(len(counts)):
        scratch = np.empty((start[v + 1] - start[v]) * elements.shape[1], dtype=np.int64)
        counts[v] = _neighbours(elements, start, corners, v, scratch)


@njit(cache=True, parallel=True)
def _rows(elements, pairs, weights, start, corners, indptr, indices, data):
    """Row v of the Laplacian: its columns (:func:`_neighbours`) and ``Σ ±w`` over the element edges at v."""
    n_corners = elements.shape[1]
    for v in prange(len(indptr) - 1):
        lo, hi = indptr[v], indptr[v + 1]
        if lo == hi:
            continue
        scratch = np.empty((start[v + 1] - start[v]) * n_corners, dtype=np.int64)
        _neighbours(elements, start, corners, v, scratch)
        indices[lo:hi] = scratch[: hi - lo]
        data[lo:hi] = 0.0
        diagonal = lo + np.searchsorted(indices[lo:hi], v)
        for k in range(start[v], start[v + 1]):
            f = corners[k] // n_corners
            c = corners[k] - f * n_corners
            for e in range(len(pairs)):
                if pairs[e, 0] == c:
                    other = elements[f, pairs[e, 1]]
                elif pairs[e, 1] == c:
                    other = elements[f, pairs[e, 0]]
                else:
                    continue
                w = weights[f, e]
                data[lo + np.searchsorted(indices[lo:hi], other)] -= w
                data[diagonal] += w
