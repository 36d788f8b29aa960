"""The lift's per-surface-vertex passes against the straightforward computations they replace: the surface sample
against a sort by (tet, index), the residuals over every vertex against the embedding matrix, the flipped faces
against the dot product of the face normals, the rows of the embedding against the full matrix, and the location
of points in a refined proxy against a search over every child."""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.edit.lift import Lift, surface_sample
from nerfedit_plugin.geometry.normals import face_normals, turned_faces
from nerfedit_plugin.geometry.refine import bisect


def sorted_sample(tets_of: np.ndarray, indices: np.ndarray, budget: int) -> np.ndarray:
    """The sample by its definition: per tet, in index order, every ``max(count // k, 1)``-th vertex, at most ``k``,
    ``k`` the largest keeping the total within the budget (at least 1)."""
    if budget == 0 or len(indices) <= budget:
        return indices
    tets = tets_of[indices]
    order = np.lexsort((indices, tets))
    first = np.flatnonzero(np.r_[True, tets[order][1:] != tets[order][:-1]])
    counts = np.diff(np.r_[first, len(order)])
    k = max([k for k in range(1, counts.max() + 1) if np.minimum(counts, k).sum() <= budget], default=1)
    rank = np.arange(len(order)) - np.repeat(first, counts)
    step = np.repeat(np.maximum(counts // k, 1), counts)
    keep = (rank % step == 0) & (rank // step < k)
    return np.sort(indices[order[keep]])


def test_surface_sample_equals_the_sort_by_tet_and_index():
    rng = np.random.default_rng(7)
    for tets, vertices, budget in ((40, 5000, 700), (300, 20000, 301), (7, 900, 3), (70000, 90000, 80000)):
        tets_of = rng.integers(0, tets, vertices) ** 2 % tets  # uneven occupancy
        indices = np.sort(rng.choice(vertices, vertices * 4 // 5, replace=False))
        np.testing.assert_array_equal(surface_sample(tets_of, indices, budget), sorted_sample(tets_of, indices, budget))
    shuffled = rng.permutation(indices)  # any order of the same indices gives the same sample
    np.testing.assert_array_equal(surface_sample(tets_of, shuffled, 5000), sorted_sample(tets_of, indices, 5000))


def test_residuals_everywhere_equal_the_embedding_matrix(capsule, capsule_proxy):
    from tests.edit.test_lift import bend

    lift = Lift(capsule_proxy, capsule, "tet-arap")
    moved = bend(capsule.vertices)
    deformed = capsule_proxy.vertices + 0.01 * np.sin(7 * capsule_proxy.vertices)
    report = lift.report(deformed, moved, 0, 0.0)
    everywhere = lift._everywhere(report, deformed, moved)
    residual = np.linalg.norm(capsule_proxy.embedding_matrix() @ deformed - moved, axis=1) / capsule.bbox_diagonal
    assert abs(everywhere.residual_max - residual.max()) <= 1e-15
    assert abs(everywhere.residual_rms - np.sqrt(np.mean(residual**2))) <= 1e-15
    rows = np.arange(0, capsule.n_vertices, 3)
    sliced = capsule_proxy.embedding_matrix(rows)
    assert (sliced != capsule_proxy.embedding_matrix()[rows]).nnz == 0 and sliced.shape[0] == len(rows)


def test_turned_faces_equal_the_sign_of_the_normals_dot_product(capsule):
    from tests.edit.test_lift import bend

    rng = np.random.default_rng(1)
    for moved in (
        bend(capsule.vertices, 3.0),
        capsule.vertices * [1, 1, -1],
        capsule.vertices + rng.normal(0, 0.05, capsule.vertices.shape),
    ):
        dot = np.einsum("ij,ij->i", face_normals(capsule.vertices, capsule.faces), face_normals(moved, capsule.faces))
        np.testing.assert_array_equal(turned_faces(capsule.vertices, moved, capsule.faces), dot < 0)


def test_points_located_in_the_refined_proxy_reproduce_themselves(capsule, capsule_proxy):
    """Each surface vertex goes to a child of its tet whose barycentrics reproduce it, and to the child whose smallest
    barycentric is largest (a search over every child); an uncut tet's points keep their barycentrics."""
    proxy = capsule_proxy
    marked = np.zeros(len(proxy.tets), dtype=bool)
    marked[proxy.embed_tets[:: max(1, capsule.n_vertices // 50)]] = True
    refinement = bisect(proxy.vertices, proxy.tets, marked)
    tet, bary = refinement.locate(capsule.vertices, proxy.embed_tets, proxy.embed_bary)
    assert np.array_equal(refinement.parent[tet], proxy.embed_tets)
    placed = np.einsum("mj,mjd->md", bary, refinement.vertices[refinement.tets[tet]])
    assert np.abs(placed - capsule.vertices).max() < 1e-12
    for m in range(0, capsule.n_vertices, 97):
        children = np.flatnonzero(refinement.parent == proxy.embed_tets[m])
        if len(children) == 1:
            assert tet[m] == children[0] and np.array_equal(bary[m], proxy.embed_bary[m])
            continue
        smallest = []
        for child in children:
            corners = refinement.vertices[refinement.tets[child]]
            l123 = np.linalg.solve((corners[1:] - corners[0]).T, capsule.vertices[m] - corners[0])
            smallest.append(min(1 - l123.sum(), *l123))
        assert tet[m] == children[int(np.argmax(smallest))]
