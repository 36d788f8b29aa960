"""Conforming bisection refinement: the refined mesh fills the same volume with no hanging vertex, keeps every tet's
orientation, and carries piecewise-linear maps exactly."""

import numpy as np
import pytest

from nerfedit_plugin.edit.proxy import embed_points
from nerfedit_plugin.geometry.refine import bisect
from nerfedit_plugin.geometry.tets import boundary_faces, kuhn_grid, orient_tets, tet_signed_volumes


@pytest.fixture(scope="module")
def grid():
    """A 3×3×3 Kuhn grid of the unit cube, jittered inside so no edge lengths tie."""
    vertices, tets = kuhn_grid(3)
    inner = ((vertices > 0) & (vertices < 1)).all(axis=1)
    vertices[inner] += np.random.default_rng(1).uniform(-0.05, 0.05, (inner.sum(), 3))
    return vertices, orient_tets(vertices, tets)


def face_counts(tets):
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]]), 1)
    return np.unique(faces, axis=0, return_counts=True)[1]


def area(vertices, faces):
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()


@pytest.mark.parametrize("seed", range(4))
def test_random_markings_refine_conformingly(grid, seed):
    """Same volume, every tet positive, no face shared by more than two tets, and the boundary's area unchanged: a
    hanging vertex would leave an interior face with one tet, adding its area to the boundary."""
    vertices, tets = grid
    marked = np.random.default_rng(seed).random(len(tets)) < 0.15
    refined = bisect(vertices, tets, marked)
    volumes = tet_signed_volumes(refined.vertices, refined.tets)
    assert (volumes > 0).all()
    assert volumes.sum() == pytest.approx(tet_signed_volumes(vertices, tets).sum(), rel=1e-12)
    assert face_counts(refined.tets).max() == 2
    assert area(refined.vertices, boundary_faces(refined.tets)) == pytest.approx(6.0, rel=1e-12)
    assert len(refined.tets) > len(tets) and len(refined.edges) == len(refined.vertices) - len(vertices)
    # every child lies in its parent: its centroid has non-negative barycentrics there
    centroids = refined.vertices[refined.tets].mean(1)
    tet, _ = embed_points(vertices, tets, centroids)
    corners = vertices[tets[refined.parent]]
    local = np.linalg.solve(
        (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1), (centroids - corners[:, 0])[..., None]
    )
    assert (local[..., 0] >= -1e-12).all() and (local[..., 0].sum(1) <= 1 + 1e-12).all()
    assert (tet >= 0).all()


def test_marking_everything_is_the_eight_way_split_and_nothing_is_the_identity(grid):
    vertices, tets = grid
    full = bisect(vertices, tets, np.ones(len(tets), dtype=bool))
    assert len(full.tets) == 8 * len(tets)
    assert np.ptp(np.bincount(full.parent)) == 0
    none = bisect(vertices, tets, np.zeros(len(tets), dtype=bool))
    np.testing.assert_array_equal(none.tets, tets)
    np.testing.assert_array_equal(none.vertices, vertices)


def test_prolong_carries_a_piecewise_linear_map_exactly(grid):
    """An affine map stays affine at the midpoints, and a point keeps its image under the coarse map when located in
    the refined mesh (Refinement.locate) and mapped there."""
    vertices, tets = grid
    rng = np.random.default_rng(2)
    refined = bisect(vertices, tets, rng.random(len(tets)) < 0.3)
    matrix, shift = rng.normal(size=(3, 3)), rng.normal(size=3)
    np.testing.assert_allclose(refined.prolong(vertices @ matrix.T + shift), refined.vertices @ matrix.T + shift)
    moved = vertices + rng.normal(scale=0.02, size=vertices.shape)  # any piecewise-linear map
    points = rng.uniform(0.01, 0.99, size=(500, 3))
    coarse, bary = embed_points(vertices, tets, points)
    tet, fine_bary = refined.locate(points, coarse, bary)
    assert (fine_bary >= -1e-12).all()
    np.testing.assert_allclose(np.einsum("mk,mkd->md", fine_bary, refined.vertices[refined.tets[tet]]), points)
    before = np.einsum("mk,mkd->md", bary, moved[tets[coarse]])
    after = np.einsum("mk,mkd->md", fine_bary, refined.prolong(moved)[refined.tets[tet]])
    np.testing.assert_allclose(after, before, atol=1e-13)
    uncut = np.bincount(refined.parent, minlength=len(tets))[coarse] == 1
    np.testing.assert_array_equal(fine_bary[uncut], bary[uncut])  # untouched tets keep their barycentrics
