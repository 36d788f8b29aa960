"""The lift on small deterministic proxies (Kuhn grids, no pytetwild): brute-force and hand-computed references for
the baselines, the report and the fold counts; exact plumbing of the ARAP and inversion-free solvers (the mutation
test's fast selection for ``nerfedit_plugin/edit/lift.py``, see bench/mutation.py)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.edit.lift import (
    Lift,
    LiftConfig,
    closest_point_displacements,
    knn3_displacements,
)
from nerfedit_plugin.edit.proxy import proxy_from_tets
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.arap import ArapSolver
from nerfedit_plugin.geometry.injective import InjectiveSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.normals import face_normals
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets, tet_signed_volumes

OCTAHEDRON_FACES = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
ROT = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
SHIFT = np.array([0.2, -0.1, 0.4])


def octahedron() -> SurfaceMesh:
    """A closed octahedron (6 vertices, 8 outward faces), slightly stretched and off-centre (no symmetric ties)."""
    axes = np.array([[0.5, 0, 0], [-0.5, 0, 0], [0, 0.5, 0], [0, -0.5, 0], [0, 0, 0.5], [0, 0, -0.5]])
    return SurfaceMesh(axes * [1.0, 0.9, 1.1] + [0.03, 0.02, 0.01], OCTAHEDRON_FACES)


@pytest.fixture(scope="module")
def grid():
    """The octahedron in a Kuhn grid of [−1, 1]³ (2 cells per axis: 27 vertices, 48 positive tets)."""
    vertices, tets = kuhn_grid(2, -1.0, 1.0)
    rest = octahedron()
    return rest, proxy_from_tets(vertices, orient_tets(vertices, tets), rest, "test")


def mild(rest: SurfaceMesh) -> np.ndarray:
    """A non-rigid edit that folds nothing (an anisotropic scaling)."""
    return rest.vertices * [1.1, 1.0, 0.9]


def folding(rest: SurfaceMesh) -> np.ndarray:
    """The top vertex pulled through the bottom one: soft ARAP follows it and inverts tets."""
    out = rest.vertices.copy()
    out[4, 2] = -0.9
    return out


def test_face_normals_are_the_unnormalised_cross_products():
    vertices = np.array([[0, 0, 0], [2, 0, 0], [0, 3, 0], [1, 1, 1], [1, 3, 1], [1, 1, 4]], dtype=float)
    got = face_normals(vertices, np.array([[0, 1, 2], [3, 4, 5], [3, 5, 4]]))
    np.testing.assert_array_equal(got, [[0, 0, 6], [6, 0, 0], [-6, 0, 0]])


def test_knn3_blends_the_three_nearest_displacements_by_inverse_distance():
    rng = np.random.default_rng(1)
    rest = rng.uniform(-1, 1, (30, 3))
    moved = rest + rng.normal(0, 0.3, rest.shape)
    points = np.concatenate([rng.uniform(-1.2, 1.2, (60, 3)), rest[7:8]])  # the last one sits on a rest point
    distance = np.linalg.norm(points[:, None] - rest[None], axis=-1)
    nearest = np.argsort(distance, axis=1)[:, :3]
    weights = 1.0 / np.maximum(np.take_along_axis(distance, nearest, 1), 1e-12)
    weights /= weights.sum(1, keepdims=True)
    expected = np.einsum("mk,mkd->md", weights, (moved - rest)[nearest])
    got = knn3_displacements(rest, moved, points)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[-1], (moved - rest)[7], rtol=0, atol=1e-10)  # on a point: its displacement


def closest_on_segment(p, a, b):
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return a + t * (b - a)


def closest_displacement(p, rest: SurfaceMesh, moved):
    """Brute force, one point: the plane projection if it falls in the triangle, else the closest point on one of
    its edges, over all triangles; → (distance to the nearest triangle, its second nearest, blended displacement)."""
    candidates = []
    for face in rest.faces:
        corners = rest.vertices[face]
        normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        q = p - (p - corners[0]) @ normal / (normal @ normal) * normal
        bary = np.array([np.cross(corners[(k + 1) % 3] - q, corners[(k + 2) % 3] - q) @ normal for k in range(3)]) / (
            normal @ normal
        )
        points = [q] if (bary >= 0).all() else []
        points += [closest_on_segment(p, corners[k], corners[(k + 1) % 3]) for k in range(3)]
        best = min(points, key=lambda x: np.linalg.norm(x - p))
        weights = np.linalg.lstsq(np.vstack([corners.T, np.ones(3)]), np.append(best, 1.0), rcond=None)[0]
        candidates.append((np.linalg.norm(best - p), weights @ (moved - rest.vertices)[face]))
    candidates.sort(key=lambda c: c[0])
    return candidates[0][0], candidates[1][0], candidates[0][1]


def test_closest_point_displacements_against_brute_force():
    rest = octahedron()
    rng = np.random.default_rng(2)
    moved = rest.vertices + rng.normal(0, 0.2, rest.vertices.shape)
    points = rng.uniform(-0.8, 0.8, (80, 3))
    got = closest_point_displacements(rest, moved, points)
    checked = 0
    for p, g in zip(points, got):
        first, second, expected = closest_displacement(p, rest, moved)
        if second - first > 1e-6:  # a unique nearest triangle
            np.testing.assert_allclose(g, expected, rtol=0, atol=1e-6)
            checked += 1
    assert checked > 20


def test_baseline_lifts_add_their_displacements_to_the_proxy(grid):
    rest, proxy = grid
    frames = np.stack([mild(rest), folding(rest)])
    for method, displacement in (
        ("knn3", lambda s: knn3_displacements(rest.vertices, s, proxy.vertices)),
        ("closest-point", lambda s: closest_point_displacements(rest, s, proxy.vertices)),
    ):
        lifted, reports = Lift(proxy, rest, method)(frames)
        assert lifted.dtype == np.float64
        for f in range(2):
            np.testing.assert_allclose(lifted[f], proxy.vertices + displacement(frames[f]), rtol=0, atol=1e-12)
            assert reports[f].iterations == 0


class _SurfaceOnly(Deformer):
    def bind(self, rest, edit):
        self.rest = rest

    def deform(self):
        return self.rest.vertices[None]


class _Shift(_SurfaceOnly):
    """In space: x ↦ R x + frame · SHIFT, returned as float32."""

    def deform_points(self, points, frame):
        return (points @ ROT.T + frame * SHIFT).astype(np.float32)


def test_direct_lift_evaluates_the_deformer_per_frame(grid):
    rest, proxy = grid
    frames = np.stack([rest.vertices @ ROT.T + f * SHIFT for f in range(2)])
    lifted, reports = Lift(proxy, rest, "direct", deformer=_Shift(DeformerConfig()))(frames)
    assert lifted.dtype == np.float64
    for f in range(2):
        expected = (proxy.vertices @ ROT.T + f * SHIFT).astype(np.float32)
        np.testing.assert_array_equal(lifted[f], expected)
        assert reports[f].iterations == 0
    with pytest.raises(NerfEditError, match=r"^--lift direct: _SurfaceOnly has no deform_points \(use tet-arap\)$"):
        Lift(proxy, rest, "direct", deformer=_SurfaceOnly(DeformerConfig()))
    with pytest.raises(NerfEditError, match=r"^--lift direct: no deformer has no deform_points \(use tet-arap\)$"):
        Lift(proxy, rest, "direct")
    Lift(proxy, rest, "knn3", deformer=_SurfaceOnly(DeformerConfig()))  # other methods do not need deform_points


def handles(top_transform=None, frames=1):
    """Bottom layer (z = −1) fixed, top layer (z = 1) moved by ``top_transform`` (fixed if None)."""
    top = {"fixed": True} if top_transform is None else {"transform": top_transform}
    return parse_edit_spec(
        {
            "frames": frames,
            "handles": [
                {"select": {"box": {"min": [-2, -2, -2], "max": [2, 2, -0.9]}}, "fixed": True},
                {"select": {"box": {"min": [-2, -2, 0.9], "max": [2, 2, 2]}}, **top},
            ],
        }
    )


def test_tet_edit_needs_handles(grid):
    rest, proxy = grid
    message = r"^--lift tet-edit: the edit spec must have handles to apply to the proxy$"
    for edit in (None, parse_edit_spec({})):
        with pytest.raises(NerfEditError, match=message):
            Lift(proxy, rest, "tet-edit", edit=edit)


@pytest.mark.parametrize("method", ["tet-arap", "tet-edit"])
def test_identity_edit_is_exactly_the_rest_proxy(grid, method):
    rest, proxy = grid
    lifted, (report,) = Lift(proxy, rest, method, edit=handles())(rest.vertices[None])
    np.testing.assert_allclose(lifted[0], proxy.vertices, rtol=0, atol=1e-12)
    assert report.residual_max < 1e-12 and report.inverted_tets == report.degenerate_tets == 0


def test_rigid_edits_give_rigid_proxies(grid):
    rest, proxy = grid
    expected = proxy.vertices @ ROT.T + SHIFT
    lifted, (report,) = Lift(proxy, rest)((rest.vertices @ ROT.T + SHIFT)[None])
    assert np.abs(lifted[0] - expected).max() < 1e-5
    assert report.residual_max < 1e-6 and report.inverted_tets == 0
    edit = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-2, -2, z0], "max": [2, 2, z1]}}, "transform": {"translate": list(SHIFT)}}
                for z0, z1 in ((-2, -0.9), (0.9, 2))
            ]
        }
    )
    lifted, (report,) = Lift(proxy, rest, "tet-edit", edit=edit)(rest.vertices[None])
    np.testing.assert_allclose(lifted[0], proxy.vertices + SHIFT, rtol=0, atol=1e-9)


@pytest.mark.parametrize("iterations, tolerance", [(2, 0.0), (100, 1e-2)])
def test_tet_arap_runs_the_configured_solver_warm_started(grid, iterations, tolerance):
    """Frame 0 starts from the knn3 lift, frame 1 from frame 0's result; the solver has the config's constraint
    weight, iteration cap and tolerance."""
    rest, proxy = grid
    config = LiftConfig(constraint_weight=30.0, max_iterations=iterations, tolerance=tolerance, refine_rounds=0)
    frames = np.stack([mild(rest), mild(rest) * 1.05 + 0.02])
    lifted, reports = Lift(proxy, rest, config=config)(frames)
    solver = ArapSolver(
        proxy.vertices, proxy.tets, energy="elements", constraints=proxy.embedding_matrix(), constraint_weight=30.0
    )
    previous = proxy.vertices + knn3_displacements(rest.vertices, frames[0], proxy.vertices)
    for f in range(2):
        result = solver.solve(
            constraint_targets=frames[f], initial=previous, max_iterations=iterations, tolerance=tolerance
        )
        np.testing.assert_allclose(lifted[f], result.vertices, rtol=0, atol=1e-13)
        assert reports[f].iterations == result.iterations
        assert reports[f].inverted_tets == 0 and 0 <= reports[f].seconds < 60
        previous = result.vertices
    assert reports[0].iterations == iterations if tolerance == 0 else reports[0].iterations < iterations


@pytest.mark.parametrize("iterations, tolerance", [(2, 0.0), (100, 1e-2)])
def test_tet_edit_runs_the_configured_solver_warm_started(grid, iterations, tolerance):
    """Frame f starts from frame f − 1's result (frame 0, at time 0, is the rest proxy)."""
    rest, proxy = grid
    edit = handles({"translate": [0.3, 0.0, 0.0]}, frames=3)
    config = LiftConfig(max_iterations=iterations, tolerance=tolerance)
    lifted, reports = Lift(proxy, rest, "tet-edit", config, edit=edit)(np.stack([rest.vertices] * 3))
    fixed, targets = edit.handle_targets(proxy.vertices)
    solver = ArapSolver(proxy.vertices, proxy.tets, energy="elements", fixed=fixed)
    previous = None
    for f in range(3):
        result = solver.solve(
            fixed_positions=targets[f], initial=previous, max_iterations=iterations, tolerance=tolerance
        )
        np.testing.assert_allclose(lifted[f], result.vertices, rtol=0, atol=1e-13)
        assert reports[f].iterations == result.iterations
        previous = result.vertices
    assert not np.allclose(lifted[1], proxy.vertices)  # frame 2 starts elsewhere than at rest


def cube():
    """One Kuhn cube [0, 1]³ (8 vertices, 6 positive tets, each of volume 1/6) around a small triangle pair."""
    vertices, tets = kuhn_grid(1)
    surface = SurfaceMesh(
        [[0.3, 0.2, 0.4], [0.6, 0.25, 0.45], [0.4, 0.6, 0.5], [0.5, 0.5, 0.2]], [[0, 1, 2], [0, 3, 1]]
    )
    return surface, proxy_from_tets(vertices, orient_tets(vertices, tets), surface, "test")


def moved_corner(proxy, x, y, z):
    """Corner (1, 0, 0) (vertex 4) moved to (x, y, z): the two tets on it, (000, 100, 110, 111) and (000, 101, 100,
    111) after orientation, get volumes (x − y)/6 and (x − z)/6; the other four keep 1/6."""
    deformed = proxy.vertices.copy()
    assert np.array_equal(deformed[4], [1, 0, 0])
    deformed[4] = [x, y, z]
    return deformed


def test_report_counts_inverted_and_degenerate_tets_by_hand():
    """Threshold: 1e-9 × the mean rest volume (1/6); volumes (x − y)/6 and (x − z)/6 (:func:`moved_corner`).
    (0, 1, 0): one inverted (−1/6), one degenerate (0). x − y = ±0.5e-9 (inside the band): degenerate, not inverted;
    x − y = −2e-9: inverted, not degenerate; x − z = 2e-9: neither. Lift.folds counts both kinds."""
    surface, proxy = cube()
    lift = Lift(proxy, surface, "knn3")
    cases = [((0.0, 1.0, 0.0), 1, 1), ((1.0, 1.0 - 0.5e-9, 1.0 - 2e-9), 0, 1), ((1.0, 1.0 + 0.5e-9, 1.0 - 2e-9), 0, 1)]
    cases += [((1.0, 1.0 + 2e-9, 1.0 - 2e-9), 1, 0), ((1.0, 0.0, 0.0), 0, 0)]
    for (x, y, z), inverted, degenerate in cases:
        deformed = moved_corner(proxy, x, y, z)
        report = lift.report(deformed, surface.vertices, 7, 0.25)
        assert (report.inverted_tets, report.degenerate_tets) == (inverted, degenerate), (x, y, z)
        assert lift.folds(deformed) == inverted + degenerate
        assert (report.iterations, report.seconds) == (7, 0.25)


def test_report_flipped_faces_at_exactly_ninety_degrees():
    """Both triangles turned by 90° about x (exact in floating point: coordinates swapped; normals (0, 0, 1/4) and
    (0, 1/4, −1/8) become perpendicular to their rest ones) are not counted; the first turned a bit further is;
    turned by 180° both are."""
    vertices, tets = kuhn_grid(1, -1.0, 1.0)
    surface = SurfaceMesh([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0.25, 0.25, 0.5]], [[0, 1, 2], [0, 3, 1]])
    proxy = proxy_from_tets(vertices, orient_tets(vertices, tets), surface, "test")
    lift = Lift(proxy, surface, "knn3")
    turned = surface.vertices[:, [0, 2, 1]] * [1, -1, 1]  # (x, y, z) ↦ (x, −z, y): 90° about x
    np.testing.assert_array_equal(
        np.einsum("ij,ij->i", face_normals(turned, surface.faces), face_normals(surface.vertices, surface.faces)), 0
    )
    further = turned.copy()
    further[2] = [0, -0.01, 0.5]  # face 0's normal gets a component −z
    half_turn = surface.vertices * [1, -1, -1]
    counts = [lift.report(proxy.vertices, s, 0, 0.0).flipped_surface_faces for s in (turned, further, half_turn)]
    assert counts == [0, 1, 2]


def test_report_residuals_by_hand():
    """The proxy scaled by 2 about the origin carries each surface vertex v to 2v: residual |v| / bbox diagonal."""
    surface, proxy = cube()
    lift = Lift(proxy, surface, "knn3")
    report = lift.report(2 * proxy.vertices, surface.vertices, 0, 0.0)
    norms = np.linalg.norm(surface.vertices, axis=1) / surface.bbox_diagonal
    assert report.residual_max == pytest.approx(norms.max(), rel=1e-12)
    assert report.residual_rms == pytest.approx(np.sqrt(np.mean(norms**2)), rel=1e-12)
    assert report.residual_max != pytest.approx(report.residual_rms, rel=1e-3)
    assert isinstance(report.residual_max, float) and isinstance(report.inverted_tets, int)


def test_inversion_free_relift_keeps_arap_where_it_does_not_fold(grid):
    """Frame 0 (no fold): the ARAP map bit for bit. Frame 1 (ARAP folds): the inversion-free solver with the lift's
    weight and Newton settings, started from frame 0 (which folds nothing), with ARAP's iterations added."""
    rest, proxy = grid
    frames = np.stack([mild(rest), folding(rest)])
    settings = dict(constraint_weight=500.0, injective_max_iterations=4, injective_tolerance=1e-3, refine_rounds=0)
    old, old_reports = Lift(proxy, rest, config=LiftConfig(injective=False, **settings))(frames)
    new, new_reports = Lift(proxy, rest, config=LiftConfig(**settings))(frames)
    assert old_reports[0].inverted_tets == 0 and old_reports[1].inverted_tets > 0
    np.testing.assert_array_equal(new[0], old[0])
    assert new_reports[0].iterations == old_reports[0].iterations
    assert new_reports[1].inverted_tets == new_reports[1].degenerate_tets == 0
    assert (tet_signed_volumes(new[1], proxy.tets) > 0).all()
    solver = InjectiveSolver(proxy.vertices, proxy.tets, proxy.embedding_matrix(), 500.0)
    expected = solver.solve(new[0], frames[1], max_iterations=4, tolerance=1e-3)
    np.testing.assert_allclose(new[1], expected.vertices, rtol=0, atol=1e-12)
    assert new_reports[1].iterations == old_reports[1].iterations + expected.iterations
    assert expected.iterations == 4  # the configured cap bites (the default 50 would not)


@pytest.mark.parametrize("iterations, tolerance", [(3, 0.0), (50, 0.2)])
def test_inversion_free_relift_starts_from_the_last_unfolded_state(grid, iterations, tolerance):
    """``unfolded`` starts from ``previous`` only when it folds nothing; else, and without one, from the rest proxy.
    Newton runs with the config's cap and tolerance (0.2 stops early: the solver's default would not)."""
    rest, proxy = grid
    config = LiftConfig(injective_max_iterations=iterations, injective_tolerance=tolerance, refine_rounds=0)
    lift = Lift(proxy, rest, config=config)
    target = folding(rest)
    solver = InjectiveSolver(proxy.vertices, proxy.tets, proxy.embedding_matrix(), 1000.0)
    unfolded = proxy.vertices * [1.1, 1.0, 0.9]
    folded = Lift(proxy, rest, config=LiftConfig(injective=False, refine_rounds=0))(target[None])[0][0]
    assert lift.folds(folded) > 0 and lift.folds(unfolded) == 0
    for previous, start in ((None, proxy.vertices), (folded, proxy.vertices), (unfolded, unfolded)):
        got, count = lift.unfolded(target, previous, 5)
        expected = solver.solve(start, target, max_iterations=iterations, tolerance=tolerance)
        np.testing.assert_allclose(got, expected.vertices, rtol=0, atol=1e-12)
        assert count == 5 + expected.iterations
        assert expected.iterations == 3 if tolerance == 0 else expected.iterations < 10


def test_tet_edit_relift_removes_the_folds_of_exact_handles(grid):
    """Top layer pushed below the bottom one: ARAP with exact handles inverts tets, the re-lift (soft handles with
    the lift's weight) none, its handles close to their targets."""
    rest, proxy = grid
    edit = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-2, -2, -2], "max": [2, 2, -0.9]}}, "fixed": True},
                {
                    "select": {"box": {"min": [-2, -2, 0.9], "max": [0.5, 2, 2]}},
                    "transform": {"translate": [0, 0, -2.6]},
                },
            ]
        }
    )
    config = LiftConfig(constraint_weight=200.0, injective_max_iterations=5, injective_tolerance=0.0)
    _, (old,) = Lift(proxy, rest, "tet-edit", LiftConfig(injective=False), edit=edit)(rest.vertices[None])
    lift = Lift(proxy, rest, "tet-edit", config, edit=edit)
    lifted, (new,) = lift(rest.vertices[None])
    assert old.inverted_tets > 0 and new.inverted_tets == new.degenerate_tets == 0
    fixed, targets = edit.handle_targets(proxy.vertices)
    assert len(proxy.vertices) - 1 not in fixed  # the last vertex is free
    soft = np.zeros((len(fixed), len(proxy.vertices)))
    soft[np.arange(len(fixed)), fixed] = 1.0
    solver = InjectiveSolver(proxy.vertices, proxy.tets, soft, 200.0)
    expected = solver.solve(proxy.vertices, targets[0], max_iterations=5, tolerance=0.0)
    np.testing.assert_allclose(lifted[0], expected.vertices, rtol=0, atol=1e-12)
    assert new.iterations == old.iterations + 5


def test_frames_are_read_as_float64():
    """A float32 frame is lifted and reported as its float64 copy. Its face (0, 1, 2) has the normal
    (0, 0, −2⁻²⁴) (flipped: the rest normal is +z), which float32 products would round to 0 (not flipped)."""
    vertices, tets = kuhn_grid(1, -1.0, 2.0)
    surface = SurfaceMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    proxy = proxy_from_tets(vertices, orient_tets(vertices, tets), surface, "test")
    frame = np.array([[0, 0, 0], [1 + 2**-11, 1 + 2**-12, 0], [1 + 2**-12, 1, 0]], dtype=np.float32)
    assert face_normals(frame.astype(np.float64), surface.faces)[0, 2] == -(2**-24)
    lifted, (report,) = Lift(proxy, surface, "knn3")(frame[None])
    expected, (expected_report,) = Lift(proxy, surface, "knn3")(frame[None].astype(np.float64))
    assert lifted.dtype == np.float64
    np.testing.assert_array_equal(lifted, expected)
    assert report.flipped_surface_faces == expected_report.flipped_surface_faces == 1
    assert report.residual_max == expected_report.residual_max


@pytest.mark.parametrize(
    "option, value, expected",
    [
        ("constraint_weight", 0.0, "a positive number"),
        ("constraint_weight", np.inf, "a positive number"),
        ("constraint_weight", np.nan, "a positive number"),
        ("max_iterations", 0, "a positive integer"),
        ("tolerance", -1e-300, "a number >= 0"),
        ("tolerance", np.inf, "a number >= 0"),
        ("injective", "yes", "true or false"),
        ("injective", 1, "true or false"),
        ("injective_max_iterations", 0, "a positive integer"),
        ("injective_tolerance", -1e-300, "a number >= 0"),
        ("injective_tolerance", np.inf, "a number >= 0"),
        ("residual_target", 0.0, "a positive number"),
        ("residual_target", np.inf, "a positive number"),
        ("refine_rounds", -1, "an integer >= 0"),
    ],
)
def test_lift_config_rejects(option, value, expected):
    with pytest.raises(NerfEditError) as error:
        LiftConfig(**{option: value})
    assert str(error.value) == f"LiftConfig.{option}: must be {expected}, got {value!r}"


def test_lift_config_accepts_the_boundaries():
    config = LiftConfig(0.5, 1, 0.0, False, 1, 0.0, 1e-300, 0)
    assert (config.constraint_weight, config.max_iterations, config.injective_max_iterations) == (0.5, 1, 1)
    assert (config.residual_target, config.refine_rounds) == (1e-300, 0)
    LiftConfig(tolerance=1e300, injective_tolerance=1e300, constraint_weight=1e300)
