"""3-D mean value coordinates: Ju et al.'s properties, agreement with their pseudo-code, degenerate positions."""

import igl
import numpy as np
import pytest
import trimesh

from deformers.cage.mean_value import mean_value_coordinates


def star_cage() -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-oriented, clearly non-convex cage (a bumpy sphere)."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(sphere.vertices)
    lon, lat = np.arctan2(v[:, 1], v[:, 0]), np.arcsin(v[:, 2])
    radius = 1.0 + 0.35 * np.sin(3 * lon) * np.cos(2 * lat)
    return v * radius[:, None] * [1.0, 0.8, 1.3], np.asarray(sphere.faces)


V, F = star_cage()
RNG = np.random.default_rng(0)
_candidates = RNG.uniform(V.min(0), V.max(0), size=(3000, 3))
_mask = igl.winding_number(V, F, _candidates) > 0.5  # libigl as the independent inside/outside oracle
INSIDE, OUTSIDE = _candidates[_mask][:600], _candidates[~_mask][:300]
SCALE = float(np.linalg.norm(V.max(0) - V.min(0)))


def ju_reference(x: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Ju, Schaefer & Warren's pseudo-code taken literally (arcsin and half-angle forms), one point."""
    d = np.linalg.norm(vertices - x, axis=1)
    u = (vertices - x) / d[:, None]
    w = np.zeros(len(vertices))
    for tri in faces:
        theta = [2 * np.arcsin(np.linalg.norm(u[tri[(k + 1) % 3]] - u[tri[(k + 2) % 3]]) / 2) for k in range(3)]
        h = sum(theta) / 2
        c = [
            2 * np.sin(h) * np.sin(h - theta[k]) / (np.sin(theta[(k + 1) % 3]) * np.sin(theta[(k + 2) % 3])) - 1
            for k in range(3)
        ]
        s = [np.sign(np.linalg.det(u[tri])) * np.sqrt(max(0.0, 1 - ck**2)) for ck in c]
        if min(abs(sk) for sk in s) <= 1e-12:
            continue
        for k in range(3):
            w[tri[k]] += (theta[k] - c[(k + 1) % 3] * theta[(k + 2) % 3] - c[(k + 2) % 3] * theta[(k + 1) % 3]) / (
                d[tri[k]] * np.sin(theta[(k + 1) % 3]) * s[(k + 2) % 3]
            )
    return w / w.sum()


def test_agrees_with_ju_pseudocode():
    points = np.concatenate([INSIDE[:15], OUTSIDE[:10]])
    ours = mean_value_coordinates(points, V, F)
    reference = np.stack([ju_reference(p, V, F) for p in points])
    assert np.abs(ours - reference).max() < 1e-9


@pytest.mark.parametrize("points", [INSIDE, OUTSIDE], ids=["inside", "outside"])
def test_partition_of_unity_and_linear_precision(points):
    w = mean_value_coordinates(points, V, F)
    assert w.shape == (len(points), len(V)) and w.dtype == np.float64
    assert np.abs(w.sum(1) - 1).max() < 1e-12
    # Points within ~1e-6 of a face's plane (outside that face) lose digits to a cancellation inherent in the
    # formula; exterior points also to cancelling front/back layers.
    tol = 1e-10 if points is INSIDE else 1e-6
    assert np.abs(w @ V - points).max() < tol * SCALE
    assert np.median(np.abs(w @ V - points)) < 1e-13 * SCALE


def test_affine_cage_map_is_reproduced():
    a = np.array([[1.2, 0.3, -0.2], [0.1, 0.7, 0.4], [-0.3, 0.2, 1.5]])
    b = np.array([0.5, -1.0, 2.0])
    w = mean_value_coordinates(INSIDE, V, F)
    assert np.abs(w @ (V @ a.T + b) - (INSIDE @ a.T + b)).max() < 1e-10 * SCALE


def test_interpolates_cage_vertices():
    w = mean_value_coordinates(V, V, F)
    assert np.array_equal(w, np.eye(len(V)))


def test_positive_inside_a_convex_cage():
    sphere = trimesh.creation.icosphere(subdivisions=1)
    points = RNG.normal(size=(300, 3))
    points *= (0.9 * RNG.uniform(size=300) ** (1 / 3) / np.linalg.norm(points, axis=1))[:, None]  # inradius ≈ 0.93
    assert mean_value_coordinates(points, sphere.vertices, sphere.faces).min() > 0


def _on_faces(n):
    faces = RNG.integers(0, len(F), n)
    bary = RNG.dirichlet([1, 1, 1], n)
    return faces, bary, np.einsum("pk,pki->pi", bary, V[F[faces]])


def test_points_on_faces_edges_and_vertices():
    faces, bary, on_face = _on_faces(100)
    w = mean_value_coordinates(on_face, V, F)
    expected = np.zeros_like(w)
    np.add.at(expected, (np.arange(100)[:, None], F[faces]), bary)
    assert np.abs(w - expected).max() < 1e-12  # a face's own barycentrics

    t = RNG.uniform(size=(100, 1))
    on_edge = t * V[F[faces, 0]] + (1 - t) * V[F[faces, 1]]
    w = mean_value_coordinates(on_edge, V, F)
    assert np.isfinite(w).all() and np.abs(w @ V - on_edge).max() < 1e-12 * SCALE
    assert np.allclose(w[np.arange(100), F[faces, 0]], t[:, 0]) and np.allclose(
        w[np.arange(100), F[faces, 1]], 1 - t[:, 0]
    )


@pytest.mark.parametrize("distance", [1e-3, 1e-6, 1e-9, 1e-11, 1e-13])
def test_stable_next_to_faces_edges_and_vertices(distance):
    faces, _, on_face = _on_faces(60)
    t = RNG.uniform(0.05, 0.95, size=(60, 1))
    on_edge = t * V[F[faces, 0]] + (1 - t) * V[F[faces, 1]]
    direction = RNG.normal(size=(180, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = np.concatenate([on_face, on_edge, V[F[faces, 2]]]) + distance * SCALE * direction
    w = mean_value_coordinates(points, V, F)
    assert np.isfinite(w).all()
    assert np.abs(w.sum(1) - 1).max() < 1e-12
    assert np.abs(w @ V - points).max() < 1e-7 * SCALE


def test_orientation_independent_and_winding_numbers():
    points = np.concatenate([INSIDE[:100], OUTSIDE[:100]])
    w, winding = mean_value_coordinates(points, V, F, return_winding=True)
    w_flipped, winding_flipped = mean_value_coordinates(points, V, F[:, ::-1], return_winding=True)
    assert np.allclose(w, w_flipped, rtol=0, atol=1e-11)
    assert np.allclose(winding[:100], 1) and np.allclose(winding[100:], 0, atol=1e-9)
    assert np.allclose(winding_flipped, -winding)


def test_chunking_and_threads_do_not_change_the_result():
    a = mean_value_coordinates(INSIDE, V, F)
    b = mean_value_coordinates(INSIDE, V, F, chunk_size=7, workers=1)
    assert np.allclose(a, b, rtol=0, atol=1e-14)


def test_points_on_the_cage_have_winding_one_half_and_vertices_interpolate():
    """On the surface the cage subtends half the sphere of directions: winding number ½ on a face, an edge and a
    vertex; at a vertex the coordinates are that vertex's indicator."""
    faces, _, on_face = _on_faces(10)
    on_edge = 0.3 * V[F[faces, 0]] + 0.7 * V[F[faces, 1]]
    points = np.concatenate([on_face, on_edge, V[F[faces, 2]]])
    w, winding = mean_value_coordinates(points, V, F, return_winding=True)
    np.testing.assert_array_equal(winding, np.full(30, 0.5))
    np.testing.assert_array_equal(w[20:], np.eye(len(V))[F[faces, 2]])
