"""Lifts: rigid edits give rigid proxies, A t' = v' holds for tet-arap, baselines and ablations behave as defined."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.lift import Lift
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.geometry.tets import tet_signed_volumes

ROT = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
SHIFT = np.array([0.2, -0.1, 0.4])


def bend(points: np.ndarray, amount: float = 0.6) -> np.ndarray:
    """A smooth non-rigid map: rotate about x by an angle growing with z (a bend of the capsule)."""
    angle = amount * np.clip(points[:, 2], 0, None)
    out = points.copy()
    out[:, 1] = points[:, 1] * np.cos(angle) - points[:, 2] * np.sin(angle)
    out[:, 2] = points[:, 1] * np.sin(angle) + points[:, 2] * np.cos(angle)
    return out


@pytest.mark.parametrize("method", ["tet-arap", "knn3", "closest-point"])
def test_identity_edit_is_identity(capsule, capsule_proxy, method):
    lifted, reports = Lift(capsule_proxy, capsule, method)(capsule.vertices[None])
    assert np.allclose(lifted[0], capsule_proxy.vertices, atol=1e-9 * capsule.bbox_diagonal)
    assert reports[0].residual_max < 1e-9 and reports[0].inverted_tets == 0


def test_rigid_edit_gives_rigid_proxy(capsule, capsule_proxy):
    moved = capsule.vertices @ ROT.T + SHIFT
    lifted, reports = Lift(capsule_proxy, capsule, "tet-arap")(moved[None])
    expected = capsule_proxy.vertices @ ROT.T + SHIFT
    assert np.abs(lifted[0] - expected).max() < 1e-4 * capsule.bbox_diagonal
    assert reports[0].residual_max < 1e-5 and reports[0].inverted_tets == 0


@pytest.mark.parametrize("method", ["knn3", "closest-point"])
def test_baselines_reproduce_translations(capsule, capsule_proxy, method):
    lifted, _ = Lift(capsule_proxy, capsule, method)((capsule.vertices + SHIFT)[None])
    assert np.allclose(lifted[0], capsule_proxy.vertices + SHIFT)


def test_tet_arap_fits_constraints_better_than_baselines(capsule, capsule_proxy):
    frames = np.stack([bend(capsule.vertices, a) for a in (0.3, 0.6)])
    lifted, reports = Lift(capsule_proxy, capsule, "tet-arap")(frames)
    assert lifted.shape == (2, len(capsule_proxy.vertices), 3)
    for report in reports:
        assert report.residual_max < 2e-3 and report.inverted_tets == 0 and report.degenerate_tets == 0
    _, knn = Lift(capsule_proxy, capsule, "knn3")(frames)
    assert reports[1].residual_rms < 0.5 * knn[1].residual_rms
    # every deformed tet keeps its orientation
    assert (tet_signed_volumes(lifted[1], capsule_proxy.tets) > 0).all()


def test_tet_edit_applies_handles_to_the_proxy(capsule, capsule_proxy):
    spec = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-1, -1, -2], "max": [1, 1, -0.5]}}, "fixed": True},
                {"select": {"box": {"min": [-1, -1, 0.5], "max": [1, 1, 2]}}, "transform": {"translate": [0, 0.3, 0]}},
            ]
        }
    )
    lifted, reports = Lift(capsule_proxy, capsule, "tet-edit", edit=spec)(capsule.vertices[None])
    idx, targets = spec.handle_targets(capsule_proxy.vertices)
    assert np.allclose(lifted[0, idx], targets[0])
    assert reports[0].inverted_tets == 0


def test_direct_lift_evaluates_the_space_map(capsule, capsule_proxy):
    from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
    from nerfedit_plugin.errors import NerfEditError

    class Surface(Deformer):
        def bind(self, rest, edit):
            self.rest = rest

        def deform(self):
            return bend(self.rest.vertices)[None]

    class Bend(Surface):
        def deform_points(self, points, frame):
            return bend(points)

    lifted, _ = Lift(capsule_proxy, capsule, "direct", deformer=Bend(DeformerConfig()))(bend(capsule.vertices)[None])
    assert np.allclose(lifted[0], bend(capsule_proxy.vertices))
    with pytest.raises(NerfEditError, match="has no deform_points"):
        Lift(capsule_proxy, capsule, "direct", deformer=Surface(DeformerConfig()))


def closest_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentrics (M,3) of the closest points of triangle (a, b, c) to points p (M,3): Ericson, *Real-Time
    Collision Detection* §5.1.5 (Voronoi regions of the corners, then the edges, else the face)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ap @ ab, ap @ ac
    bp, cp = p - b, p - c
    d3, d4, d5, d6 = bp @ ab, bp @ ac, cp @ ab, cp @ ac
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    v, w = vb / denom, vc / denom  # inside the face
    out = np.column_stack([1 - v - w, v, w])
    regions = [  # later regions take precedence: corners last
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), lambda: np.column_stack([1 - d1 / (d1 - d3), d1 / (d1 - d3), 0 * d1])),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), lambda: np.column_stack([1 - d2 / (d2 - d6), 0 * d2, d2 / (d2 - d6)])),
        (
            (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
            lambda: np.column_stack(
                [0 * d4, 1 - (d4 - d3) / ((d4 - d3) + (d5 - d6)), (d4 - d3) / ((d4 - d3) + (d5 - d6))]
            ),
        ),
        ((d1 <= 0) & (d2 <= 0), lambda: np.tile([1.0, 0.0, 0.0], (len(p), 1))),
        ((d3 >= 0) & (d4 <= d3), lambda: np.tile([0.0, 1.0, 0.0], (len(p), 1))),
        ((d6 >= 0) & (d5 <= d6), lambda: np.tile([0.0, 0.0, 1.0], (len(p), 1))),
    ]
    with np.errstate(divide="ignore", invalid="ignore"):
        for mask, bary in regions:
            out = np.where(mask[:, None], bary(), out)
    return out


@pytest.fixture(scope="module")
def lumpy():
    """A small irregular closed mesh (an icosphere stretched and jittered: 42 vertices, 80 faces), a non-rigid motion of
    it (the bend plus a random displacement per vertex) and query points around, inside and outside it."""
    import trimesh

    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    rng = np.random.default_rng(5)
    sphere = trimesh.creation.icosphere(subdivisions=1)
    vertices = np.asarray(sphere.vertices) * [0.5, 0.7, 1.0] + rng.uniform(-0.05, 0.05, (len(sphere.vertices), 3))
    rest = SurfaceMesh(vertices, np.asarray(sphere.faces))
    moved = bend(vertices, 0.8) + rng.normal(0, 0.1, vertices.shape)
    points = rng.uniform(-1.2, 1.2, (400, 3)) * [0.7, 0.9, 1.3]
    return rest, moved, points


def test_closest_point_lift_blends_the_closest_triangles_corners(lumpy):
    """Against brute force: each point's closest point on every triangle (Ericson), the nearest of them, and the
    barycentric blend of that triangle's corner displacements (corner k weighs the displacement of faces[:, k]).
    Where several triangles are nearly as close (a shared edge or corner, or a near tie), any of them will do."""
    from nerfedit_plugin.edit.lift import closest_point_displacements

    rest, moved, points = lumpy
    corners = rest.vertices[rest.faces]  # (F,3,3)
    displacement = (moved - rest.vertices)[rest.faces]  # (F,3,3)
    bary = np.stack([closest_on_triangle(points, *corners[f]) for f in range(len(corners))], 1)  # (M,F,3)
    closest = np.einsum("mfk,fkd->mfd", bary, corners)
    distance = np.linalg.norm(closest - points[:, None], axis=-1)  # (M,F)
    candidates = np.einsum("mfk,fkd->mfd", bary, displacement)
    got = closest_point_displacements(rest, moved, points)
    near = distance <= distance.min(1, keepdims=True) + 1e-6
    error = np.where(near, np.linalg.norm(candidates - got[:, None], axis=-1), np.inf).min(1)
    assert error.max() < 1e-5
    inside = (bary[np.arange(len(points)), distance.argmin(1)] > 1e-3).all(1)
    assert inside.sum() > 50  # many points project into a face's interior, not just onto edges and corners
    assert np.abs(got).max() > 0.2  # the displacement is far from a translation: a wrong blend shows


def test_knn3_lift_weighs_the_three_nearest_vertices_by_inverse_distance(lumpy):
    from nerfedit_plugin.edit.lift import knn3_displacements

    rest, moved, points = lumpy
    distance = np.linalg.norm(points[:, None] - rest.vertices[None], axis=-1)  # (M,V)
    order = np.argsort(distance, axis=1)
    nearest = order[:, :3]
    gap = np.take_along_axis(distance, order[:, 2:4], 1)
    assert (gap[:, 1] - gap[:, 0] > 1e-9).all()  # no ties for the third nearest
    weights = 1.0 / np.take_along_axis(distance, nearest, 1)
    weights /= weights.sum(1, keepdims=True)
    expected = np.einsum("mk,mkd->md", weights, (moved - rest.vertices)[nearest])
    np.testing.assert_allclose(knn3_displacements(rest.vertices, moved, points), expected, rtol=0, atol=1e-12)


# ---- inversion-free lift -----------------------------------------------------------------------------------------
def tube_mesh(radius=0.25, length=2.0, rings=41, sides=24):
    """Closed tube along z (z ∈ [−1, 1]), a vertex ring every 0.05."""
    import trimesh

    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    z = np.linspace(-length / 2, length / 2, rings)
    profile = np.array([[0, z[0]], *[[radius, zz] for zz in z], [0, z[-1]]])
    mesh = trimesh.creation.revolve(profile, sections=sides)
    return SurfaceMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


def cage_tip_edit(rest, proxy=None):
    """(tet proxy, frames) of the issue's folding case on a tube along z of length 2: a cage edit (automatic cage)
    that fixes the base and moves the tip sideways by 0.35 (17.5 % of the length). The proxy is ``proxy`` or, when
    none is given, ``build_proxy(rest)`` (pytetwild: a different one each run)."""
    from deformers.cage import CageConfig, CageDeformer
    from nerfedit_plugin.edit.proxy import ProxyConfig, build_proxy

    edit = {
        "cage": "auto",
        "handles": [
            {"select": {"box": {"min": [-1, -1, -2], "max": [1, 1, -0.7]}}, "fixed": True},
            {"select": {"box": {"min": [-1, -1, 0.7], "max": [1, 1, 2]}}, "transform": {"translate": [0.35, 0, 0]}},
        ],
    }
    deformer = CageConfig().setup()
    deformer.bind(rest, parse_edit_spec(edit, CageDeformer.spec_keys))
    return proxy if proxy is not None else build_proxy(rest, ProxyConfig()), deformer.deform()


@pytest.fixture(scope="module")
def tube():
    """The tube of :func:`tube_mesh` (1k vertices), its tet proxy and the cage edit of :func:`cage_tip_edit`. The proxy
    is one pytetwild build shipped in ``fixtures/tube_proxy.npz`` (919 vertices, 3696 tets): over 12 fresh builds the
    lift ratios the tests bound ranged 0.99–1.24× (residual max) and once 1.39× in CI, so a per-session build made the
    bound depend on the draw."""
    from nerfedit_plugin.edit.proxy import proxy_from_tets

    rest = tube_mesh()
    with np.load(Path(__file__).parents[1] / "fixtures" / "tube_proxy.npz") as data:
        proxy = proxy_from_tets(data["vertices"], data["tets"], rest, "fixtures/tube_proxy.npz")
    return (rest, *cage_tip_edit(rest, proxy))


def test_tet_arap_lifts_the_folding_tube_edit_without_inverted_tets(tube):
    """Soft ARAP alone (today's lift, ``injective=False``) folds tets of the tube; the default lift folds none, with
    a residual close to soft ARAP's (1.035× max, 1.07× rms on the shipped proxy; bound 1.25×: an injective map cannot
    follow where the folded one cut corners)."""
    from nerfedit_plugin.edit.lift import LiftConfig

    rest, proxy, frames = tube
    _, (old,) = Lift(proxy, rest, config=LiftConfig(injective=False, refine_rounds=0))(frames)
    lifted, (new,) = Lift(proxy, rest, config=LiftConfig(refine_rounds=0))(frames)
    assert old.inverted_tets > 0
    assert new.inverted_tets == 0 and new.degenerate_tets == 0
    assert (tet_signed_volumes(lifted[0], proxy.tets) > 0).all()
    assert new.residual_max <= 1.25 * old.residual_max and new.residual_max < 2e-2  # 5.9e-3 on the shipped proxy
    assert new.residual_rms <= 1.25 * old.residual_rms


def test_tet_edit_lifts_a_folding_twist_without_inverted_tets(tube):
    """tet-edit with the tip turned by 170° about the axis and pushed down by 0.7: ARAP with exact handles folds
    tets; the inversion-free re-lift (soft handles) folds none and keeps the handles within 1e-4 of the bbox."""
    from nerfedit_plugin.edit.lift import LiftConfig

    rest, proxy, _ = tube
    tip = {"translate": [0.2, 0, -0.7], "rotate": {"axis": [0, 0, 1], "degrees": 170, "center": [0, 0, 1]}}
    spec = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-1, -1, -2], "max": [1, 1, -0.7]}}, "fixed": True},
                {"select": {"box": {"min": [-1, -1, 0.7], "max": [1, 1, 2]}}, "transform": tip},
            ]
        }
    )
    _, (old,) = Lift(proxy, rest, "tet-edit", LiftConfig(injective=False), edit=spec)(rest.vertices[None])
    lifted, (new,) = Lift(proxy, rest, "tet-edit", edit=spec)(rest.vertices[None])
    assert old.inverted_tets > 0 and new.inverted_tets == 0 and new.degenerate_tets == 0
    idx, targets = spec.handle_targets(proxy.vertices)
    assert np.abs(lifted[0, idx] - targets[0]).max() < 1e-4 * rest.bbox_diagonal


def test_lift_keeps_the_arap_map_where_it_does_not_fold(capsule, capsule_proxy):
    """Where soft ARAP folds nothing its lift is kept bit for bit (tolerance 0: residual and map are today's).
    The inversion-free solver run on the same frame from rest lands close to it: residual within 25 % (0.99× on the
    shipped proxy; 0.91–1.17× over 80 fresh pytetwild proxies, one 1.35×), map within 2e-2 of the bbox diagonal (a
    different energy, symmetric Dirichlet, away from the surface)."""
    from nerfedit_plugin.edit.lift import LiftConfig
    from nerfedit_plugin.geometry.injective import InjectiveSolver

    frames = np.stack([bend(capsule.vertices, a) for a in (0.3, 0.6)])
    old, old_reports = Lift(capsule_proxy, capsule, config=LiftConfig(injective=False, refine_rounds=0))(frames)
    new, new_reports = Lift(capsule_proxy, capsule, config=LiftConfig(refine_rounds=0))(frames)
    assert all(r.inverted_tets == 0 for r in old_reports)
    np.testing.assert_array_equal(new, old)
    assert [r.residual_max for r in new_reports] == [r.residual_max for r in old_reports]
    lift = Lift(capsule_proxy, capsule, config=LiftConfig(refine_rounds=0))
    solver = InjectiveSolver(capsule_proxy.vertices, capsule_proxy.tets, lift.embedding, 1000.0)
    fresh = solver.solve(capsule_proxy.vertices, frames[1], tolerance=1e-4).vertices
    report = lift.report(fresh, frames[1], 0, 0.0)
    assert report.inverted_tets == 0 and report.residual_max <= 1.25 * old_reports[1].residual_max
    assert np.abs(fresh - old[1]).max() < 2e-2 * capsule.bbox_diagonal


def test_lift_of_the_conformance_kits_edit_is_inversion_free(proxy_cache):
    """The conformance kit's mesh and generic two-frame handle edit (ARAP deformer), lifted: no inverted tets."""
    from deformers.arap import ArapConfig
    from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy
    from nerfedit_plugin.testing import default_edit, default_mesh

    rest = default_mesh()
    deformer = ArapConfig().setup()
    deformer.bind(rest, parse_edit_spec(default_edit(rest), deformer.spec_keys))
    frames = deformer.deform()
    proxy, _ = cached_proxy(rest, ProxyConfig(), proxy_cache)
    _, reports = Lift(proxy, rest)(frames)
    assert all(r.inverted_tets == 0 and r.degenerate_tets == 0 for r in reports)


def test_lift_config_checks_the_injective_options():
    from nerfedit_plugin.edit.lift import LiftConfig
    from nerfedit_plugin.errors import NerfEditError

    for bad in ({"injective_max_iterations": 0}, {"injective_tolerance": -1.0}, {"injective": "yes"}):
        with pytest.raises(NerfEditError, match=next(iter(bad))):
            LiftConfig(**bad)


# ---- refinement where the fit misses the surface -----------------------------------------------------------------
def test_refinement_brings_the_tube_edit_within_the_residual_target():
    """On a fine tube (trimesh's cylinder subdivided to edges ≤ 0.05: 24k vertices, long thin triangles) the cage edit
    misses the surface by ~1e-2 × bbox on the proxy as built; the default lift refines the proxy where it misses
    (bisection) until the surface is within ``residual_target`` (2e-3), folding no tet. Refining only where vertices
    miss the target, and giving up on a vertex after one round that did not help it, ended at 2.4–2.7e-3 (its fit
    waits for its neighbours' tets); aiming at half the target and two rounds' patience, at 1.0–1.2e-3. The refined
    proxy still embeds the rest surface exactly, and its lift is a frame of the refined proxy."""
    import trimesh

    from nerfedit_plugin.edit.lift import LiftConfig
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    cylinder = trimesh.creation.cylinder(radius=0.25, height=2.0, sections=24)
    rest = SurfaceMesh(*trimesh.remesh.subdivide_to_size(cylinder.vertices, cylinder.faces, max_edge=0.05))
    proxy, frames = cage_tip_edit(rest)
    _, (coarse,) = Lift(proxy, rest, config=LiftConfig(refine_rounds=0))(frames)
    lift = Lift(proxy, rest)
    lifted, (report,) = lift(frames)
    assert coarse.residual_max > 5e-3  # the case needs the refinement
    assert lift.refinements >= 1 and len(lift.proxy.tets) > len(proxy.tets)
    assert report.residual_max <= 2e-3 and report.inverted_tets == report.degenerate_tets == 0
    assert lifted.shape == (1, len(lift.proxy.vertices), 3)
    assert (tet_signed_volumes(lifted[0], lift.proxy.tets) > 0).all()
    np.testing.assert_allclose(lift.embedding @ lift.proxy.vertices, rest.vertices, atol=1e-12)
    np.testing.assert_array_equal(lift.proxy.vertices[: len(proxy.vertices)], proxy.vertices)  # coarse ones kept


def test_no_refinement_where_the_built_proxy_fits(capsule, capsule_proxy):
    """A rigid motion is fitted exactly by any proxy: the default lift refines nothing and equals the lift with
    refinement switched off, bit for bit (and does not look for crossing surface faces)."""
    from nerfedit_plugin.edit.lift import LiftConfig

    rotation = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    rotation *= np.sign(np.linalg.det(rotation))
    frames = (capsule.vertices @ rotation.T + [0.2, -0.1, 0.3])[None]
    lift = Lift(capsule_proxy, capsule)
    lifted, (report,) = lift(frames)
    plain, _ = Lift(capsule_proxy, capsule, config=LiftConfig(refine_rounds=0))(frames)
    assert lift.refinements == 0 and lift.proxy is capsule_proxy
    np.testing.assert_array_equal(lifted, plain)
    assert report.residual_max < 1e-6 and report.crossing_surface_faces is None  # within the target: not checked


def test_crossing_faces_are_counted_near_the_missed_vertices(capsule, capsule_proxy):
    """The capsule's top half mirrored through z = 0 lies on the bottom half: no map of space follows it, the lift
    misses it, and the frame counts the crossing faces near the vertices it misses: the crossing faces of the whole
    surface (the test on all faces, minus those crossing at rest) whose corners lie within ``CROSSING_RADIUS`` × bbox
    of a missed vertex."""
    from scipy.spatial import cKDTree

    from nerfedit_plugin.edit.lift import CROSSING_RADIUS, LiftConfig

    mirrored = capsule.vertices.copy()
    mirrored[mirrored[:, 2] > 0, 2] *= -1
    lift = Lift(capsule_proxy, capsule, config=LiftConfig(refine_rounds=0))
    lifted, (report,) = lift(mirrored[None])
    moved = capsule.with_vertices(mirrored)
    whole = moved.self_intersecting_faces() & ~capsule.self_intersecting_faces()
    assert report.residual_max > 2e-3 and 0 < report.crossing_surface_faces <= np.count_nonzero(whole)
    missed = mirrored[lift.surface[lift.misfit(lifted[0], mirrored) > 2e-3]]
    distance, _ = cKDTree(missed).query(mirrored[capsule.faces[whole]].reshape(-1, 3))
    near = (distance.reshape(-1, 3) <= CROSSING_RADIUS * capsule.bbox_diagonal).all(axis=1)
    # at most those, and nearly all: a face whose partner lies outside the neighbourhood is missed (248 / 244 seen)
    assert 0.9 * np.count_nonzero(near) <= report.crossing_surface_faces <= np.count_nonzero(near)


def test_refine_rounds_bound_the_refinement(tube):
    """A residual target no proxy meets stops at the bound: one round with ``refine_rounds=1``, of MAX_BISECTIONS
    bisections."""
    from nerfedit_plugin.edit.lift import MAX_BISECTIONS, LiftConfig

    rest, proxy, frames = tube
    lift = Lift(proxy, rest, config=LiftConfig(refine_rounds=1, residual_target=1e-9))
    lifted, (report,) = lift(frames)
    assert lift.refinements == MAX_BISECTIONS == lift.proxy.info["refinements"] == 2
    assert lifted.shape[1] == len(lift.proxy.vertices) and report.inverted_tets == 0


def test_refined_lift_fits_closer_and_stays_close_to_the_lift_as_built(capsule, capsule_proxy):
    """Where the lift as built folds nothing, the refined lift (target: half its worst residual) has a smaller max and
    RMS residual in every frame, no inverted tets, and moves the built proxy's vertices by at most 2e-2 × bbox (a
    different energy, symmetric Dirichlet, takes over where refined tets fold under ARAP; 0.4–1.4e-2 seen)."""
    from nerfedit_plugin.edit.lift import LiftConfig

    frames = np.stack([bend(capsule.vertices, a) for a in (0.3, 0.6)])
    built, built_reports = Lift(capsule_proxy, capsule, config=LiftConfig(refine_rounds=0))(frames)
    assert all(r.inverted_tets == 0 for r in built_reports)
    target = 0.5 * max(r.residual_max for r in built_reports)
    lift = Lift(capsule_proxy, capsule, config=LiftConfig(residual_target=target))
    refined, reports = lift(frames)
    assert lift.refinements >= 1
    for old, new in zip(built_reports, reports):
        assert new.residual_max < old.residual_max and new.residual_rms < old.residual_rms
        assert new.inverted_tets == new.degenerate_tets == 0
    assert np.abs(refined[:, : len(capsule_proxy.vertices)] - built).max() < 2e-2 * capsule.bbox_diagonal


def test_bisections_aim_at_half_the_target_while_an_active_vertex_misses_it(capsule, capsule_proxy):
    """Per vertex ⌈log₄(residual / (AIM × target))⌉ bisections once an active vertex misses the target — also for
    vertices within it but over the aim —, none while every active vertex is within (a vertex given up, however far
    off, refines nothing and keeps nobody refining)."""
    from nerfedit_plugin.edit.lift import AIM, LiftConfig

    lift = Lift(capsule_proxy, capsule, config=LiftConfig(residual_target=1e-3))
    aim = AIM * 1e-3
    residual = np.array([0.5 * aim, 0.9 * aim, 1.5 * aim, 1.1e-3, 3.9 * aim, 4.1 * aim, 16.5 * aim])
    np.testing.assert_array_equal(lift.bisections_needed(residual), [0, 0, 1, 1, 1, 2, 3])
    np.testing.assert_array_equal(lift.bisections_needed(residual[:3]), [0, 0, 0])  # all within the target
    active = np.array([True, True, True, False, True, True, True])  # vertex 3 (over the target) given up
    np.testing.assert_array_equal(lift.bisections_needed(residual[:4], active[:4]), [0, 0, 0, 0])
    np.testing.assert_array_equal(lift.bisections_needed(residual, active), [0, 0, 1, 0, 1, 2, 3])


def test_a_round_that_helps_no_vertex_is_undone(capsule, capsule_proxy):
    """Two coincident surface vertices (vertex 0 split into a seam: one of its faces takes a copy) sent 0.1 apart: no
    map of space fits both, however fine the proxy. The refinement round cuts no residual by a fifth, so it is undone:
    the proxy as built, the lift as without refinement."""
    from nerfedit_plugin.edit.lift import LiftConfig
    from nerfedit_plugin.edit.proxy import proxy_from_tets
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    faces = capsule.faces.copy()
    face = np.flatnonzero((faces == 0).any(axis=1))[0]
    faces[face][faces[face] == 0] = capsule.n_vertices
    twin = SurfaceMesh(np.concatenate([capsule.vertices, capsule.vertices[:1]]), faces)
    proxy = proxy_from_tets(capsule_proxy.vertices, capsule_proxy.tets, twin, "test")
    frame = twin.vertices.copy()
    frame[0] += [0.05, 0, 0]
    frame[-1] -= [0.05, 0, 0]
    lift = Lift(proxy, twin)
    lifted, (report,) = lift(frame[None])
    plain, (expected,) = Lift(proxy, twin, config=LiftConfig(refine_rounds=0))(frame[None])
    assert report.residual_max > 2e-3 and lift.refinements == 0 and lift.proxy is proxy
    np.testing.assert_array_equal(lifted, plain)
    assert report.residual_max == expected.residual_max


def test_stray_vertices_do_not_pull_the_lift(capsule, capsule_proxy):
    """A vertex of no face (sample meshes have them: the airplane's pulled its wings' lift to 7e-2 × bbox) is not a
    constraint: the surface moved rigidly while a stray vertex stays put lifts to that rigid motion."""
    from nerfedit_plugin.edit.proxy import proxy_from_tets
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    stray = SurfaceMesh(np.concatenate([capsule.vertices, [[0.0, 0.0, 0.3]]]), capsule.faces)
    proxy = proxy_from_tets(capsule_proxy.vertices, capsule_proxy.tets, stray, "test")
    frame = np.concatenate([capsule.vertices @ ROT.T + SHIFT, [[0.0, 0.0, 0.3]]])
    lift = Lift(proxy, stray)
    lifted, (report,) = lift(frame[None])
    assert lift.refinements == 0 and report.residual_max < 1e-6
    np.testing.assert_allclose(lifted[0], proxy.vertices @ ROT.T + SHIFT, atol=1e-6)


def test_surface_sample_keeps_every_occupied_tet_within_the_budget():
    """Against a brute-force count per tet: the sample is sorted and distinct, holds min(count, k) vertices of each
    tet for the largest k whose total fits the budget (at least one per occupied tet), and is every vertex at or under
    the budget or with budget 0."""
    from nerfedit_plugin.edit.lift import surface_sample

    rng = np.random.default_rng(0)
    tets_of = rng.integers(0, 300, size=20_000) ** 2 // 300  # uneven: a few tets hold many vertices
    indices = np.arange(0, 20_000, 2)
    occupied = np.bincount(tets_of[indices])
    for budget in (100, 1000, 4000):
        kept = surface_sample(tets_of, indices, budget)
        assert np.all(np.diff(kept) > 0) and np.isin(kept, indices).all()
        k = max([1] + [k for k in range(1, occupied.max() + 1) if np.minimum(occupied, k).sum() <= budget])
        np.testing.assert_array_equal(np.bincount(tets_of[kept], minlength=len(occupied)), np.minimum(occupied, k))
        assert len(kept) <= max(budget, np.count_nonzero(occupied))
    np.testing.assert_array_equal(surface_sample(tets_of, indices, len(indices)), indices)
    np.testing.assert_array_equal(surface_sample(tets_of, indices, 0), indices)


def test_a_lift_on_a_surface_sample_fits_the_whole_surface_and_reports_it(capsule, capsule_proxy):
    """The capsule subdivided twice (midpoints: the same surface, 16× the faces) with a sample of a quarter of its
    vertices (still ~2.5 per proxy vertex): a rigid motion is lifted exactly; a bend lifts as the lift of every
    vertex does, and the residuals reported are those of every surface vertex (recomputed here)."""
    import trimesh

    from nerfedit_plugin.edit.lift import LiftConfig
    from nerfedit_plugin.edit.proxy import proxy_from_tets
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    fine = trimesh.Trimesh(capsule.vertices, capsule.faces, process=False).subdivide().subdivide()
    fine = SurfaceMesh(np.asarray(fine.vertices), np.asarray(fine.faces))
    proxy = proxy_from_tets(capsule_proxy.vertices, capsule_proxy.tets, fine, "test")
    budget = fine.n_vertices // 4
    sampled = Lift(proxy, fine, config=LiftConfig(max_constraints=budget, refine_rounds=0))
    assert len(sampled.surface) <= budget < len(sampled.everywhere) == fine.n_vertices
    lifted, _ = sampled((fine.vertices @ ROT.T + SHIFT)[None])
    np.testing.assert_allclose(lifted[0], proxy.vertices @ ROT.T + SHIFT, atol=1e-5 * fine.bbox_diagonal)
    frame = bend(fine.vertices)
    lifted, (report,) = sampled(frame[None])
    full, (expected,) = Lift(proxy, fine, config=LiftConfig(refine_rounds=0))(frame[None])
    residual = np.linalg.norm(proxy.embedding_matrix() @ lifted[0] - frame, axis=1) / fine.bbox_diagonal
    assert report.residual_max == pytest.approx(residual.max(), rel=1e-9)
    assert report.residual_max < 2 * expected.residual_max < 2e-3
    assert np.abs(lifted[0] - full[0]).max() < 0.01 * fine.bbox_diagonal
