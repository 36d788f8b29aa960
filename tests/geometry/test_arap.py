"""ARAP solver (surface and tet) and the ``arap`` deformer plugin.

Oracles: libigl's cotangent Laplacian and ARAP solver, batched SVD for the rotation fit, exact rigid motions
(zero-energy minimisers), exact handle placement, the non-increasing energy of local/global iterations.
"""

from __future__ import annotations

import functools
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.spatial.transform import Rotation

from deformers.arap import ArapConfig, ArapDeformer
from nerfedit_plugin.edit.spec import load_edit_spec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import _arap_kernel as kernel
from nerfedit_plugin.geometry.arap import ArapSolver, fit_rotations, fit_rotations_numpy
from nerfedit_plugin.geometry.cotangent import ELEMENT_EDGES, cotangent_weights
from nerfedit_plugin.geometry.injective import InjectiveSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.soft_constraints import SoftConstraints
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets

igl = pytest.importorskip("igl")

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


# ---- meshes ----------------------------------------------------------------------------------------
def sample_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    path = os.path.join(os.path.dirname(pymeshlab.__file__), "tests", "sample_meshes", name)
    mesh = trimesh.load(path, process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def tet_grid(n: int = 6, jitter: float = 0.25, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A box [0,2]×[0,1]×[0,1] of n·(n/2)·(n/2) cubes, 6 Kuhn tets each, interior vertices jittered."""
    dims = np.array([n, n // 2, n // 2])
    vertices, tets = kuhn_grid(dims, 0.0, dims / (n // 2))
    rng = np.random.default_rng(seed)
    interior = np.all((vertices > 0) & (vertices < vertices.max(0)), axis=1)
    vertices[interior] += rng.uniform(-jitter, jitter, (interior.sum(), 3)) / (n // 2)
    return vertices, orient_tets(vertices, tets)


@functools.cache
def marching_cubes_torus(resolution: int = 40) -> tuple[np.ndarray, np.ndarray]:
    from skimage.measure import marching_cubes

    x = np.linspace(-1.5, 1.5, resolution)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    sdf = (np.sqrt(X**2 + Y**2) - 1.0) ** 2 + Z**2 - 0.4**2
    verts, faces, _, _ = marching_cubes(sdf, 0.0, spacing=(x[1] - x[0],) * 3)
    return verts.astype(np.float64), faces.astype(np.int64)


def bbox(vertices: np.ndarray) -> float:
    return float(np.linalg.norm(vertices.max(0) - vertices.min(0)))


def rigid(points: np.ndarray, degrees: float = 45.0, seed: int = 1) -> np.ndarray:
    """A rotation by ``degrees`` about a random axis and a random translation."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    rot = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
    return points @ rot.T + rng.normal(size=3)


def bend_handles(vertices: np.ndarray, degrees: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Fix the lowest 10% along x, rotate the highest 10% about z by ``degrees`` and lift it."""
    lo, hi = np.quantile(vertices[:, 0], [0.1, 0.9])
    fixed, moved = np.flatnonzero(vertices[:, 0] <= lo), np.flatnonzero(vertices[:, 0] >= hi)
    centre = vertices[moved].mean(0)
    rot = Rotation.from_rotvec([0, 0, np.radians(degrees)]).as_matrix()
    targets = (vertices[moved] - centre) @ rot.T + centre + [0, 0.1 * bbox(vertices), 0]
    return np.concatenate([fixed, moved]), np.concatenate([vertices[fixed], targets])


def assembled_laplacian(vertices, elements) -> sp.csr_matrix:
    pairs = ELEMENT_EDGES[elements.shape[1]]
    i, j = elements[:, pairs[:, 0]].ravel(), elements[:, pairs[:, 1]].ravel()
    w = cotangent_weights(vertices, elements).ravel()
    n = len(vertices)
    return sp.coo_matrix(
        (np.concatenate([-w, -w, w, w]), (np.concatenate([i, j, i, j]), np.concatenate([j, i, i, j]))), shape=(n, n)
    ).tocsr()


# ---- building blocks ---------------------------------------------------------------------------------
def test_fit_rotations_is_the_optimal_rotation():
    rng = np.random.default_rng(0)
    g = 500
    rank1 = rng.normal(size=(g, 3, 1)) @ rng.normal(size=(g, 1, 3))
    cases = {
        "random": rng.normal(size=(g, 3, 3)),
        "rank 2": rng.normal(size=(g, 3, 2)) @ rng.normal(size=(g, 2, 3)),
        "negative det": rng.normal(size=(g, 3, 3)) * [[1, 1, 1], [1, 1, 1], [-1, -1, -1]],
        "rank 1 and empty": np.concatenate([rank1, np.zeros((9, 3, 3))]),
        "near rotations": Rotation.random(g, random_state=1).as_matrix().transpose(0, 2, 1)
        @ (np.eye(3) + 1e-3 * rng.normal(size=(g, 3, 3))),
    }
    for name, cov in cases.items():
        stacked = np.ascontiguousarray(cov.transpose(1, 0, 2).reshape(-1, 3))
        ours, reference = fit_rotations(stacked), fit_rotations_numpy(stacked)
        rot = ours.reshape(3, -1, 3).transpose(1, 2, 0)  # R_g[c, d]
        assert np.allclose(rot @ rot.transpose(0, 2, 1), np.eye(3), atol=1e-12), name
        assert np.allclose(np.linalg.det(rot), 1.0, atol=1e-12), name
        best = np.einsum("gab,gba->g", reference.reshape(3, -1, 3).transpose(1, 2, 0), cov)
        reached = np.einsum("gab,gba->g", rot, cov)
        assert np.all(reached >= best - 1e-12 * (1 + np.abs(best))), name  # tr(R S) is maximal
        # and it is the maximiser igl finds too
        igl_rot = igl.fit_rotations(stacked, False).reshape(3, -1, 3).transpose(1, 0, 2)
        assert np.allclose(np.einsum("gab,gba->g", igl_rot, cov), reached, atol=1e-10), name


def energy_terms(n_vertices, elements, weights, energy):
    """Brute force: the terms ``w ‖(x_i − x_j) − R_g (p_i − p_j)‖²`` as flat ``(g, i, j, w)`` and the group count."""
    n_elements, corners = elements.shape
    pairs = ELEMENT_EDGES[corners]
    rows = []
    for f in range(n_elements):
        for e, (a, b) in enumerate(pairs):
            i, j, w = elements[f, a], elements[f, b], weights[f, e]
            if energy == "elements":
                groups = [f]
            elif energy == "spokes_and_rims":
                groups = list(elements[f])
            else:
                groups = [i, j]
            rows += [(g, i, j, w) for g in groups]
    g, i, j, w = (np.array(c) for c in zip(*rows, strict=True))
    return (g, i, j, w), n_elements if energy == "elements" else n_vertices


def covariance_matrix(rest, elements, energy) -> tuple[sp.csr_matrix, tuple]:
    """The sparse ``K (N, 3G)``, ``K[v, a·G + g] = Σ_{terms of g} w (p_i − p_j)_a ([v = i] − [v = j])``: ``Kᵀ X``
    stacks the covariances ``S_g`` (row ``a·G + g`` = row a), ``K R`` (the ``R_gᵀ`` stacked) is the global step's
    right-hand side."""
    (g, i, j, w), n_groups = energy_terms(len(rest), elements, cotangent_weights(rest, elements), energy)
    edges = w[:, None] * (rest[i] - rest[j])
    cols = (np.arange(3)[:, None] * n_groups + g).ravel()
    values = np.concatenate([edges.T.ravel(), -edges.T.ravel()])
    k_rows = np.concatenate([np.tile(i, 3), np.tile(j, 3)])
    shape = (len(rest), 3 * n_groups)
    return sp.csr_matrix((values, (k_rows, np.concatenate([cols, cols]))), shape=shape), (g, i, j, w)


@pytest.mark.parametrize("energy", ["spokes_and_rims", "spokes", "elements", "tet elements", "tet spokes"])
def test_kernels_are_the_sparse_covariance_formulas(energy):
    """Covariances ``Kᵀ X``, the energy (with the rotations of the SVD oracle), the residual sum, ``K R`` and plain
    local/global iterates built from the brute-force sparse ``K``, against the compiled kernels."""
    vertices, elements = tet_grid(6) if energy.startswith("tet") else decimated_bunny(2000)
    energy = energy.split()[-1]
    handles, targets = bend_handles(vertices, degrees=50.0)
    solver = ArapSolver(vertices, elements, energy=energy, fixed=handles)
    k, (g, i, j, w) = covariance_matrix(solver.rest, elements, energy)
    laplacian = {"elements": 1, "spokes": 2}.get(energy, elements.shape[1]) * assembled_laplacian(vertices, elements)
    x = solver.rest + 0.05 * bbox(vertices) * np.random.default_rng(3).normal(size=vertices.shape)

    rotations, value = solver._local(x, None)
    covariances = k.T @ x
    ours = solver._scratch()[1]  # (G,3,3) S_g[a, c]
    assert np.abs(ours.transpose(1, 0, 2).reshape(-1, 3) - covariances).max() <= 1e-12 * np.abs(covariances).max()
    reference = fit_rotations_numpy(covariances)  # R_gᵀ stacked
    stacked = rotations.transpose(2, 0, 1).reshape(-1, 3)
    assert np.abs(stacked - reference).max() <= 1e-8
    rest_energy = np.sum(solver.rest * (laplacian @ solver.rest))
    expected = np.sum(x * (laplacian @ x)) - 2 * np.sum(reference * covariances) + rest_energy
    assert value == pytest.approx(expected, rel=1e-12)
    turned = np.einsum("tca,ta->tc", rotations[g], solver.rest[i] - solver.rest[j])
    residuals = np.dot(w, np.sum((x[i] - x[j] - turned) ** 2, axis=1))
    assert residuals == pytest.approx(expected, rel=1e-10)
    terms = np.empty(len(elements))
    kernel.residual_energy(x, solver.rest, elements, solver._pairs, solver._weights, rotations, solver._mode, terms)
    assert terms.sum() == pytest.approx(residuals, rel=1e-12)
    rhs = (k @ stacked)[solver.free]
    assert np.abs(solver._rotated_edges(rotations) - rhs).max() <= 1e-12 * np.abs(rhs).max()

    # moving free vertices only: refitting the groups a solve can change gives the full energy and right-hand side
    moved = x.copy()
    moved[solver.free] += 0.02 * bbox(vertices) * np.random.default_rng(4).normal(size=(len(solver.free), 3))
    if elements.shape[1] == 3:  # (the tet grid's handles are one layer thin)
        assert 0 < len(solver._active[1]) < solver.n_groups  # the handles' interiors are left out
    full_rotations, full_value = solver._local(moved, None)
    active_rotations, active_value = solver._local(moved, None, active=True)
    assert active_value == pytest.approx(full_value, rel=1e-12)
    assert np.array_equal(active_rotations[solver._active[1]], full_rotations[solver._active[1]])
    assert np.array_equal(solver._rotated_edges(active_rotations), solver._rotated_edges(full_rotations))

    # plain local/global iterations of the sparse formulas (SVD rotations) are the solver's
    free, known = solver.free, solver.known
    y = solver.rest.copy()
    y[handles] = targets - solver.origin
    system = laplacian[free][:, free].toarray()
    for _ in range(5):
        y[free] = np.linalg.solve(system, k[free] @ fit_rotations_numpy(k.T @ y) - laplacian[free][:, known] @ y[known])
    result = solver.solve(targets, max_iterations=5, tolerance=0.0, anderson=0)
    assert np.abs(result.vertices - (y + solver.origin)).max() <= 1e-10 * bbox(vertices)


# ---- surface ARAP ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cow():
    return sample_mesh("cow.obj")


@pytest.mark.parametrize("method", ["anderson", "lbfgs"])
def test_identity_edit_returns_rest(cow, method):
    vertices, faces = cow
    handles, targets = bend_handles(vertices)
    result = ArapSolver(vertices, faces, fixed=handles).solve(vertices[handles], method=method)
    assert result.converged and result.iterations == 0  # E at rest is below the floor: nothing to do
    assert np.abs(result.vertices - vertices).max() <= 1e-12 * bbox(vertices)


@pytest.mark.parametrize("method", ["anderson", "lbfgs"])
def test_handles_exact_and_rigid_motion_reproduced(method):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    handles, _ = bend_handles(vertices)
    moved = rigid(vertices)
    result = ArapSolver(vertices, faces, fixed=handles).solve(moved[handles], tolerance=1e-9, method=method)
    assert np.array_equal(result.vertices[handles], moved[handles])
    assert np.abs(result.vertices - moved).max() <= 1e-6 * bbox(vertices)


@pytest.mark.parametrize("elements", ["surface", "tets"])
def test_lbfgs_reaches_the_anderson_minimum(elements):
    """Same converged minimiser, energies non-increasing, handles exact; the first L-BFGS step (no history yet) is
    the plain local/global iterate."""
    vertices, elements = tet_grid(8) if elements == "tets" else capsule()
    handles, targets = bend_handles(vertices, degrees=30.0)
    solver = ArapSolver(vertices, elements, fixed=handles)
    anderson = solver.solve(targets, max_iterations=1000, tolerance=1e-14)
    lbfgs = solver.solve(targets, max_iterations=1000, tolerance=1e-14, method="lbfgs")
    assert anderson.converged and lbfgs.converged
    assert np.abs(lbfgs.vertices - anderson.vertices).max() <= 1e-6 * bbox(vertices)
    assert lbfgs.energies[-1] == pytest.approx(anderson.energies[-1], rel=1e-9)
    assert np.all(np.diff(lbfgs.energies) <= 0) and lbfgs.energies[-1] < 0.5 * lbfgs.energies[0]
    assert np.array_equal(lbfgs.vertices[handles], targets)
    plain = solver.solve(targets, max_iterations=1, tolerance=0.0, anderson=0)
    first = solver.solve(targets, max_iterations=1, tolerance=0.0, method="lbfgs")
    assert np.abs(first.vertices - plain.vertices).max() <= 1e-12 * bbox(vertices)


@functools.cache
def decimated_bunny(faces: int = 5000) -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(os.path.join(os.path.dirname(pymeshlab.__file__), "tests", "sample_meshes", "bunny.obj"))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=faces)
    return ms.current_mesh().vertex_matrix().astype(np.float64), ms.current_mesh().face_matrix().astype(np.int64)


@pytest.mark.parametrize("energy", ["spokes_and_rims", "spokes", "elements"])
@pytest.mark.parametrize("mesh", [marching_cubes_torus, decimated_bunny])
def test_energy_non_increasing_with_negative_weights(mesh, energy):
    vertices, faces = mesh()
    assert (cotangent_weights(vertices, faces) < 0).any()  # obtuse triangles (marching-cubes slivers)
    handles, targets = bend_handles(vertices, degrees=60.0)
    solver = ArapSolver(vertices, faces, energy=energy, fixed=handles)
    plain = solver.solve(targets, max_iterations=40, tolerance=0.0, anderson=0)
    # exact local and global minimisations: no iteration may raise E (a rise would stop the solve early)
    assert plain.iterations == 40 and not plain.converged
    energies = np.array(plain.energies)
    assert np.all(np.diff(energies) <= 0) and energies[-1] < energies[1] < energies[0]
    assert solver.energy(plain.vertices) == pytest.approx(energies[-1], rel=1e-9)
    accelerated = solver.solve(targets, max_iterations=40, tolerance=0.0)
    assert np.all(np.diff(accelerated.energies) <= 0)
    assert accelerated.energies[-1] <= energies[-1]
    lbfgs = solver.solve(targets, max_iterations=40, tolerance=0.0, method="lbfgs")
    assert np.all(np.diff(lbfgs.energies) <= 0)  # the Armijo search, else the plain step
    assert lbfgs.energies[-1] <= energies[-1]
    assert np.array_equal(lbfgs.vertices[handles], targets)


def _igl_converged(vertices, elements, energy_type, handles, targets, iterations: int) -> np.ndarray:
    data = igl.ARAPData()
    data.energy = energy_type
    data.max_iter = iterations
    igl.arap_precomputation(vertices, elements, 3, handles.astype(np.int32), data)
    initial = vertices.copy()
    initial[handles] = targets
    return igl.arap_solve(targets, data, initial)


def capsule() -> tuple[np.ndarray, np.ndarray]:
    """A capsule of length 2.8 along x (small enough for libigl's plain iterations to converge quickly)."""
    mesh = trimesh.creation.capsule(height=2.0, radius=0.4, count=[24, 24])
    return np.asarray(mesh.vertices)[:, [2, 1, 0]].copy(), np.asarray(mesh.faces, dtype=np.int64)


@pytest.mark.parametrize(
    "energy, igl_energy",
    [("spokes_and_rims", "ARAP_ENERGY_TYPE_SPOKES_AND_RIMS"), ("spokes", "ARAP_ENERGY_TYPE_SPOKES")],
)
def test_surface_arap_agrees_with_libigl(energy, igl_energy):
    """Both converged (per-triangle ELEMENTS rotations converge too slowly on surfaces: see the iterate test)."""
    vertices, faces = capsule()
    handles, targets = bend_handles(vertices, degrees=30.0)
    ours = ArapSolver(vertices, faces, energy=energy, fixed=handles).solve(targets, max_iterations=500, tolerance=1e-12)
    assert ours.converged
    theirs = _igl_converged(vertices, faces, getattr(igl, igl_energy), handles, targets, 300)
    assert np.abs(ours.vertices - theirs).max() <= 1e-4 * bbox(vertices)
    rest_distance = np.abs(theirs - vertices).max()
    assert rest_distance > 0.05 * bbox(vertices)  # a real deformation, not a trivial agreement


@pytest.mark.parametrize("energy", ["spokes_and_rims", "spokes", "elements", "tet elements"])
def test_plain_iterations_are_libigls(energy):
    """Without acceleration every iterate is libigl's (up to its single-precision rotations)."""
    vertices, elements = tet_grid(8) if energy.startswith("tet") else capsule()
    energy = energy.split()[-1]
    handles, targets = bend_handles(vertices, degrees=30.0)
    ours = ArapSolver(vertices, elements, energy=energy, fixed=handles)
    result = ours.solve(targets, max_iterations=15, tolerance=0.0, anderson=0)
    igl_energy = getattr(igl, f"ARAP_ENERGY_TYPE_{energy.upper()}")
    theirs = _igl_converged(vertices, elements, igl_energy, handles, targets, 15)
    assert np.abs(result.vertices - theirs).max() <= 1e-4 * bbox(vertices)
    assert ours.energy(theirs) == pytest.approx(result.energies[-1], rel=1e-4)


def test_tet_arap_agrees_with_libigl():
    vertices, tets = tet_grid(8)
    handles, targets = bend_handles(vertices, degrees=30.0)
    ours = ArapSolver(vertices, tets, fixed=handles).solve(targets, max_iterations=500, tolerance=1e-12)
    assert ours.converged
    theirs = _igl_converged(vertices, tets, igl.ARAP_ENERGY_TYPE_ELEMENTS, handles, targets, 300)
    assert np.abs(ours.vertices - theirs).max() <= 1e-4 * bbox(vertices)


# ---- tet ARAP with soft constraints --------------------------------------------------------------------
def barycentric_rows(tets: np.ndarray, n_vertices: int, count: int, seed: int = 0) -> sp.csr_matrix:
    """``count`` random points in random tets: rows with 4 non-zeros summing to 1."""
    rng = np.random.default_rng(seed)
    which = rng.integers(0, len(tets), count)
    bary = rng.dirichlet(np.ones(4), count)
    rows = np.repeat(np.arange(count), 4)
    return sp.csr_matrix((bary.ravel(), (rows, tets[which].ravel())), shape=(count, n_vertices))


@pytest.mark.parametrize("method", ["anderson", "lbfgs"])
def test_soft_constraints_rigid_targets_give_rigid_result(method):
    vertices, tets = tet_grid()
    constraints = barycentric_rows(tets, len(vertices), 2 * len(vertices))  # more rows than vertices
    solver = ArapSolver(vertices, tets, energy="elements", constraints=constraints, constraint_weight=100.0)
    moved = rigid(vertices)
    result = solver.solve(constraint_targets=constraints @ moved, tolerance=1e-12, method=method)
    assert np.abs(result.vertices - moved).max() <= 1e-6 * bbox(vertices)
    assert np.abs(constraints @ result.vertices - constraints @ moved).max() <= 1e-6 * bbox(vertices)


def test_soft_constraints_track_a_bend_and_warm_start():
    vertices, tets = tet_grid()
    constraints = barycentric_rows(tets, len(vertices), 2 * len(vertices))
    solver = ArapSolver(vertices, tets, energy="elements", constraints=constraints, constraint_weight=1e3)
    radius = 4.0  # bend the bar of length 2 along x into an arc about z: a smooth non-rigid target
    angle = vertices[:, 0] / radius
    arm = radius - vertices[:, 1]
    bent = np.stack([arm * np.sin(angle), radius - arm * np.cos(angle), vertices[:, 2]], 1)
    targets = constraints @ bent
    cold = solver.solve(constraint_targets=targets, max_iterations=300)
    start = np.abs(constraints @ vertices - targets).max()
    residual = np.abs(constraints @ cold.vertices - targets).max()
    assert residual < 0.05 * start
    warm = solver.solve(constraint_targets=targets, initial=cold.vertices, max_iterations=300)
    assert warm.iterations < cold.iterations / 3 and warm.energies[-1] <= cold.energies[-1] * (1 + 1e-6)


def test_shared_soft_constraints_solve_like_their_matrix():
    """An ArapSolver and an InjectiveSolver given one SoftConstraints (the lift shares its CᵀC) solve as with the
    matrix itself, and hold the same matrix."""
    vertices, tets = tet_grid()
    constraints = barycentric_rows(tets, len(vertices), 2 * len(vertices))
    targets = constraints @ (vertices * [1.1, 1.0, 0.9])
    shared = SoftConstraints(constraints)
    own = ArapSolver(vertices, tets, energy="elements", constraints=constraints, constraint_weight=1e3)
    given = ArapSolver(vertices, tets, energy="elements", constraints=shared, constraint_weight=1e3)
    assert given.solve(constraint_targets=targets).energies == own.solve(constraint_targets=targets).energies
    injective = InjectiveSolver(vertices, tets, shared, 1e3)
    assert injective.constraints is given.constraints is shared.matrix
    assert injective.energy(vertices, targets) == InjectiveSolver(vertices, tets, constraints, 1e3).energy(
        vertices, targets
    )


# ---- errors ---------------------------------------------------------------------------------------------
def test_component_without_handle_is_an_error():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    other = sphere.copy()
    other.apply_translation([3, 0, 0])
    both = trimesh.util.concatenate([sphere, other])
    vertices, faces = np.asarray(both.vertices), np.asarray(both.faces, dtype=np.int64)
    with pytest.raises(NerfEditError, match=f"component of {len(other.vertices)} of the {len(vertices)} vertices"):
        ArapSolver(vertices, faces, fixed=[0])
    ArapSolver(vertices, faces, fixed=[0, len(sphere.vertices)])  # one handle per component is enough


def test_bad_arguments_are_named():
    vertices, faces = trimesh.creation.icosphere(subdivisions=1).vertices, trimesh.creation.icosphere(1).faces
    with pytest.raises(NerfEditError, match="unknown energy"):
        ArapSolver(vertices, faces, energy="rims", fixed=[0])
    with pytest.raises(NerfEditError, match="out of range"):
        ArapSolver(vertices, faces, fixed=[len(vertices)])
    with pytest.raises(NerfEditError, match="constraint_weight"):
        ArapSolver(vertices, faces, constraints=sp.eye(len(vertices)), constraint_weight=0.0)
    solver = ArapSolver(vertices, faces, fixed=[0, 1])
    with pytest.raises(NerfEditError, match="fixed_positions"):
        solver.solve(np.zeros((3, 3)))
    with pytest.raises(NerfEditError, match="unknown method"):
        solver.solve(method="newton")


def test_unreferenced_vertex_stays_put():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.vstack([sphere.vertices, [[5.0, 5.0, 5.0]]])
    handles, targets = bend_handles(np.asarray(sphere.vertices))
    result = ArapSolver(vertices, sphere.faces, fixed=handles).solve(targets)
    assert np.array_equal(result.vertices[-1], vertices[-1])


# ---- the deformer plugin ----------------------------------------------------------------------------------
def cow_spec(vertices: np.ndarray, frames: int) -> dict:
    lo, hi = vertices.min(0), vertices.max(0)
    head = vertices[np.argmax(vertices[:, 2])]
    return {
        "handles": [
            {
                "select": {"box": {"min": lo.tolist(), "max": [hi[0], lo[1] + 0.2 * (hi[1] - lo[1]), hi[2]]}},
                "fixed": True,
            },
            {
                "select": {"sphere": {"center": head.tolist(), "radius": 0.15 * bbox(vertices)}},
                "transform": {"translate": [0, 0.1, 0], "rotate": {"axis": [1, 0, 0], "degrees": 30}},
            },
        ],
        "frames": frames,
    }


def test_deformer_through_config_and_edit_spec(cow):
    vertices, faces = cow
    rest = SurfaceMesh(vertices, faces)
    edit = parse_edit_spec(cow_spec(vertices, frames=3), ArapDeformer.spec_keys, source="cow.json")
    deformer = ArapConfig().setup()
    assert isinstance(deformer, ArapDeformer)
    deformer.bind(rest, edit)
    frames = deformer.deform()
    assert frames.shape == (3, len(vertices), 3)
    assert np.abs(frames[0] - vertices).max() <= 1e-12 * bbox(vertices)  # t = 0 is the rest pose
    handles, targets = edit.handle_targets(vertices)
    assert np.array_equal(frames[:, handles], targets)
    assert all(r.converged for r in deformer.results)
    converged = ArapSolver(vertices, faces, fixed=handles).solve(targets[-1], tolerance=1e-12, max_iterations=1000)
    assert converged.converged
    assert deformer.results[-1].energies[-1] <= converged.energies[-1] * (1 + 1e-4)  # the warm-started path gets there


def test_deformer_reports_spec_errors_before_factorising(cow):
    vertices, faces = cow
    rest = SurfaceMesh(vertices, faces)
    spec = cow_spec(vertices, frames=1)
    spec["handles"][1]["select"] = {"sphere": {"center": [100.0, 0, 0], "radius": 0.01}}
    with pytest.raises(NerfEditError, match=r"cow.json: handles\[1\].select.sphere: selects no points"):
        ArapConfig().setup().bind(rest, parse_edit_spec(spec, ArapDeformer.spec_keys, source="cow.json"))
    two = trimesh.util.concatenate(
        [trimesh.creation.icosphere(2), trimesh.creation.icosphere(2).apply_translation([3, 0, 0])]
    )
    spec = {"handles": [{"select": {"indices": [0]}, "transform": {"translate": [0, 0.1, 0]}}]}
    with pytest.raises(NerfEditError, match=r"two.json: handles: .*component of \d+ of the \d+ vertices"):
        ArapConfig().setup().bind(SurfaceMesh(two.vertices, two.faces), parse_edit_spec(spec, source="two.json"))


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("arap_*.json")), ids=lambda p: p.name)
def test_example_specs_select_the_intended_regions(path):
    """``configs/arap_<mesh>_<edit>.json`` are edits of the pymeshlab sample mesh ``<mesh>.obj``."""
    spec = load_edit_spec(path, ArapDeformer.spec_keys)
    vertices, _ = sample_mesh(path.stem.split("_")[1] + ".obj")
    handles, targets = spec.handle_targets(vertices)
    assert 0.05 * len(vertices) < len(handles) < 0.8 * len(vertices)
    assert np.abs(targets[-1] - vertices[handles]).max() > 0.02 * bbox(vertices)  # something moves


def test_superlu_fallback_gives_the_same_solution(monkeypatch):
    vertices, faces = capsule()
    handles, targets = bend_handles(vertices, degrees=30.0)
    with_cholespy = ArapSolver(vertices, faces, fixed=handles).solve(targets, max_iterations=20, tolerance=0.0)
    monkeypatch.setitem(sys.modules, "cholespy", None)  # import fails → SuperLU
    with_superlu = ArapSolver(vertices, faces, fixed=handles).solve(targets, max_iterations=20, tolerance=0.0)
    assert np.abs(with_superlu.vertices - with_cholespy.vertices).max() <= 1e-9 * bbox(vertices)


def test_vertex_with_only_degenerate_elements_is_named():
    vertices, faces = capsule()
    vertices = np.vstack([vertices, [[10.0, 0, 0], [11.0, 0, 0], [12.0, 0, 0]]])  # a collinear (zero-area) triangle
    n = len(vertices)
    faces = np.vstack([faces, [[n - 3, n - 2, n - 1]]])
    with pytest.raises(NerfEditError, match=f"vertex {n - 2} has no stiffness"):
        ArapSolver(vertices, faces, fixed=[0, n - 3])


def test_bad_solve_arguments_say_whether_the_shape_or_the_values_are_wrong():
    """A wrong shape names the expected one; NaN/inf at the right shape is counted (not "must be finite (N, 3), got
    (N, 3)")."""
    from nerfedit_plugin.errors import NerfEditError

    sphere = trimesh.creation.icosphere(subdivisions=1)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    solver = ArapSolver(vertices, faces, fixed=[0, 1])
    nan = vertices.copy()
    nan[3] = np.nan
    for kwargs, message in [
        ({"fixed_positions": vertices[:3]}, r"ARAP: fixed_positions must have shape \(2, 3\), got \(3, 3\)"),
        ({"fixed_positions": nan[[0, 3]]}, r"ARAP: fixed_positions holds 3 non-finite values"),
        ({"initial": vertices[:-1]}, rf"ARAP: initial must have shape \({len(vertices)}, 3\), got"),
        ({"initial": nan}, r"ARAP: initial holds 3 non-finite values"),
    ]:
        with pytest.raises(NerfEditError, match=message):
            solver.solve(**kwargs)
