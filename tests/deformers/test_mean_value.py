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


# ---- the tolerance bands (mutation tests: each band is probed just inside and just outside) -------------------------
def _lowest_faces(vertex_ids):
    """For each vertex, the lowest-indexed face on it and its corner slot there."""
    faces = np.array([int(np.flatnonzero((F == v).any(1))[0]) for v in vertex_ids])
    return faces, np.array([int(np.flatnonzero(F[f] == v)[0]) for f, v in zip(faces, vertex_ids)])


def _toward_centroid(vertices, faces, vertex_ids):
    """Unit vectors in each face's plane from the vertex toward the face's centroid, and that distance."""
    toward = vertices[F[faces]].mean(1) - vertices[vertex_ids]
    length = np.linalg.norm(toward, axis=1, keepdims=True)
    return toward / length, length


@pytest.mark.parametrize("size", [1.0, 0.01], ids=["unit", "small"])
def test_vertex_band(size):
    """Within VERTEX_EPS × the cage's bbox diagonal of a vertex (0.95×) the coordinates are that vertex's indicator;
    at 1.05× (a point in the plane of the vertex's lowest-indexed face, toward its centroid) they are that face's
    barycentrics (1 − 2s, s, s) (the face band holds), not an indicator. The small cage (diagonal < 1) keeps the
    band relative."""
    from deformers.cage.mean_value import VERTEX_EPS

    vertices, scale = V * size, SCALE * size
    ids = np.arange(0, len(V), 9)
    faces, slots = _lowest_faces(ids)
    unit, length = _toward_centroid(vertices, faces, ids)
    for factor in (0.95, 1.05):
        d = factor * VERTEX_EPS * scale
        w = mean_value_coordinates(vertices[ids] + d * unit, vertices, F)
        if factor < 1:
            np.testing.assert_array_equal(w, np.eye(len(V))[ids])
        else:
            s = d / (3 * length[:, 0])
            expected = np.zeros_like(w)
            expected[np.arange(len(ids))[:, None], F[faces]] = s[:, None]
            expected[np.arange(len(ids)), ids] = 1 - 2 * s
            np.testing.assert_allclose(w, expected, rtol=0, atol=1e-15)
            assert (w[np.arange(len(ids)), ids] < 1).all()


def _edges_and_bisectors(count):
    """``count`` interior edges (a, b) with the outward unit bisector of their two faces' normals."""
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    owner = np.tile(np.arange(len(F)), 3)
    order = np.lexsort((directed[:, 1], directed[:, 0]))
    lookup = {tuple(e): o for e, o in zip(directed[order], owner[order])}
    pick = np.linspace(0, len(directed) - 1, count).astype(int)
    pairs = directed[pick]
    bisector = normals[owner[pick]] + normals[[lookup[(b, a)] for a, b in pairs]]
    return pairs, bisector / np.linalg.norm(bisector, axis=1, keepdims=True)


def test_edge_band_off_the_faces():
    """Off both faces of an edge along their normals' bisector (so in no face's plane band): at 0.95 × EDGE_EPS ×
    scale from the edge the coordinates are exactly the linear interpolation along it (by distance to the ends,
    others 0); at 1.05× the mean value formula, close to it but with every other weight not all zero."""
    from deformers.cage.mean_value import EDGE_EPS

    pairs, bisector = _edges_and_bisectors(24)
    t = np.linspace(0.2, 0.8, len(pairs))[:, None]
    on_edge = (1 - t) * V[pairs[:, 0]] + t * V[pairs[:, 1]]
    rows = np.arange(len(pairs))
    for factor in (0.95, 1.05):
        points = on_edge + factor * EDGE_EPS * SCALE * bisector
        w = mean_value_coordinates(points, V, F)
        da, db = (np.linalg.norm(points - V[pairs[:, k]], axis=1) for k in (0, 1))
        expected = np.zeros_like(w)
        expected[rows, pairs[:, 0]], expected[rows, pairs[:, 1]] = db / (da + db), da / (da + db)
        others = w.copy()
        others[rows, pairs[:, 0]] = others[rows, pairs[:, 1]] = 0
        if factor < 1:
            np.testing.assert_allclose(w, expected, rtol=0, atol=1e-15)
            np.testing.assert_array_equal(others, 0)
        else:
            np.testing.assert_allclose(w, expected, rtol=0, atol=1e-6)
            assert (np.abs(others).max(1) > 0).all()


def test_plane_band_off_a_face():
    """Along a face's normal from an interior point (barycentrics ≥ 0.2): at 0.95 × PLANE_EPS × scale the
    coordinates are exactly the face's barycentrics (others 0), at 1.05× the mean value formula (others not 0)."""
    from deformers.cage.mean_value import PLANE_EPS

    faces, bary, on_face = _on_faces(40)
    bary = 0.2 + 0.4 * bary  # every barycentric in [0.2, 0.6]
    on_face = np.einsum("pk,pki->pi", bary, V[F[faces]])
    normals = np.cross(V[F[faces, 1]] - V[F[faces, 0]], V[F[faces, 2]] - V[F[faces, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rows = np.arange(len(faces))[:, None]
    for factor in (0.95, 1.05):
        w = mean_value_coordinates(on_face + factor * PLANE_EPS * SCALE * normals, V, F)
        expected = np.zeros_like(w)
        expected[rows, F[faces]] = bary
        np.testing.assert_allclose(w, expected, rtol=0, atol=1e-10)
        others = w.copy()
        others[rows, F[faces]] = 0
        if factor < 1:
            np.testing.assert_array_equal(others, 0)
        else:
            assert (np.abs(others).max(1) > 0).all()


def test_bary_band_beyond_a_corner():
    """In a face's plane just beyond a corner c (away from the centroid: barycentrics (−s, −s, 1 + 2s) on the other
    corners and c): with s = 0.5 × BARY_EPS the point is on the face, clipped to c's indicator exactly; with
    s = 2 × BARY_EPS it is not (the mean value formula: close to the indicator, not equal)."""
    from deformers.cage.mean_value import BARY_EPS

    ids = np.arange(3, len(V), 11)
    faces, _ = _lowest_faces(ids)
    unit, length = _toward_centroid(V, faces, ids)
    for factor in (0.5, 2.0):
        points = V[ids] - 3 * factor * BARY_EPS * length * unit  # t = 3s along c − centroid
        w = mean_value_coordinates(points, V, F)
        indicator = np.eye(len(V))[ids]
        if factor < 1:
            np.testing.assert_array_equal(w, indicator)
        else:
            np.testing.assert_allclose(w, indicator, rtol=0, atol=1e-6)
            assert (w != indicator).any(1).all()


def test_in_the_plane_of_a_face_outside_it():
    """A point in a face's plane outside the face: that face subtends no solid angle (it is skipped), the others
    still reproduce the point."""
    faces = np.arange(0, len(F), 23)
    corners = V[F[faces]]
    points = np.einsum("k,pki->pi", [-0.6, 0.8, 0.8], corners)  # barycentrics (−0.6, 0.8, 0.8): beyond an edge
    w = mean_value_coordinates(points, V, F)
    assert np.abs(w.sum(1) - 1).max() < 1e-12
    assert np.abs(w @ V - points).max() < 1e-9 * SCALE


def test_an_unreferenced_cage_vertex_gets_no_weight():
    stray = np.concatenate([V, [[0.05, -0.1, 0.02]]])  # inside the cage and its bounding box
    w = mean_value_coordinates(INSIDE[:30], stray, F)
    assert w.shape == (30, len(V) + 1)
    np.testing.assert_array_equal(w[:, -1], 0)
    np.testing.assert_allclose(w[:, :-1], mean_value_coordinates(INSIDE[:30], V, F), rtol=0, atol=1e-12)


def test_far_from_the_origin():
    """A cage 1e8 away from the origin: coordinates are translation invariant (the computation is centred on the cage;
    the translated coordinates are exact in float64 relative to each other, Sterbenz)."""
    shift = np.array([1e8, -2e8, 3e8])
    vertices, points = V + shift, INSIDE[:40] + shift
    w = mean_value_coordinates(points, vertices, F)
    reference = mean_value_coordinates(points - shift, vertices - shift, F)
    np.testing.assert_allclose(w, reference, rtol=0, atol=1e-12)


def test_degenerate_positions_raise_no_warnings():
    """The 0/0 and x/0 at vertices, edges and faces are overwritten afterwards: no RuntimeWarning reaches the caller
    (the workers run in threads: the warning filter is process-wide)."""
    import warnings

    faces, _, on_face = _on_faces(10)
    on_edge = 0.3 * V[F[faces, 0]] + 0.7 * V[F[faces, 1]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for points in (V[:20], on_edge, on_face):
            mean_value_coordinates(points, V, F)


def test_float32_and_int32_inputs_are_read_as_float64_and_int64():
    """A float32 cage (and points, int32 faces) gives bit for bit the coordinates of its float64 copy: the cage is
    not processed in float32 (which would cost ~1e-7)."""
    vertices, points = V.astype(np.float32), INSIDE[:30].astype(np.float32)
    w = mean_value_coordinates(points, vertices, F.astype(np.int32))
    np.testing.assert_array_equal(w, mean_value_coordinates(points.astype(float), vertices.astype(float), F))
