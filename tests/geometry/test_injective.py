"""The flip-free solver: derivatives, the maximal flip-free step, injectivity under folding pulls, libigl's SLIM."""

import numpy as np
import pytest
import scipy.sparse as sp

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import injective
from nerfedit_plugin.geometry.injective import (
    InjectiveSolver,
    _element_hessians,
    _first_flattening,
    _relative_motions,
    _svd3,
    flip_free_step,
)
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets, tet_signed_volumes


def grid(cells=3, size=1.0):
    vertices, tets = kuhn_grid(cells, 0.0, size)
    return vertices, orient_tets(vertices, tets)


def selection(indices, n):
    """Sparse (len(indices), n) rows picking vertices: soft handle constraints."""
    return sp.csr_matrix((np.ones(len(indices)), (np.arange(len(indices)), indices)), shape=(len(indices), n))


def twist_targets(vertices, size, degrees=45.0, shift=(0.3, 0.0, -0.2)):
    """Bottom face (z = 0) pinned, top face (z = size) turned about z through the centre and shifted."""
    handles = np.flatnonzero((vertices[:, 2] == 0) | (vertices[:, 2] == size))
    targets = vertices[handles].copy()
    top = targets[:, 2] == size
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    centre = np.full(3, size / 2)
    targets[top] = (targets[top] - centre) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + centre + shift
    return handles, targets


def test_rest_is_the_minimum_and_derivatives_match_finite_differences():
    vertices, tets = grid(2)
    constraints = selection(np.arange(4), len(vertices))
    solver = InjectiveSolver(vertices, tets, constraints, 10.0)
    assert solver.energy(vertices, vertices[:4]) == 0.0
    rng = np.random.default_rng(0)
    targets = vertices[:4] + 0.1
    x = vertices + rng.normal(0, 0.01, vertices.shape)
    matrix, gradient = solver._newton_system(x, solver._soft.expand(vertices, targets))
    direction = rng.normal(size=x.size)
    energy = lambda flat: solver.energy(flat.reshape(-1, 3), targets)  # noqa: E731
    h = 1e-6
    numeric = (energy(x.ravel() + h * direction) - energy(x.ravel() - h * direction)) / (2 * h)
    assert numeric == pytest.approx(gradient @ direction, rel=1e-6)
    h = 1e-4  # near rest the energy is convex up to rounding: the projected Hessian is the Hessian
    curvature = (energy(x.ravel() + h * direction) - 2 * energy(x.ravel()) + energy(x.ravel() - h * direction)) / h**2
    assert curvature == pytest.approx(direction @ (matrix @ direction), rel=5e-3)
    assert np.linalg.eigvalsh(matrix.toarray()).min() > 0  # projected: positive definite


def test_analytic_eigensystem_matches_the_projected_9x9_hessian():
    """The per-tet Hessians from the closed-form eigensystem equal the 9×9 Hessian in J (its closed form, Teran-style
    products of J⁻¹) clamped by a numerical eigendecomposition, on deformations far from rest (twist modes negative)."""
    vertices, tets = grid(2)
    solver = InjectiveSolver(vertices, tets, selection(np.arange(4), len(vertices)), 10.0)
    rng = np.random.default_rng(3)
    jac = solver.jacobians(vertices + rng.normal(0, 0.12, vertices.shape))
    jac = jac[np.linalg.det(jac) > 0]
    b, scale = solver.gradient_map[: len(jac)], 0.25 * solver.volumes[: len(jac)]
    inv = np.linalg.inv(jac)
    inv_t = inv.transpose(0, 2, 1)
    s, t = inv_t @ inv, inv @ inv_t
    q = s @ inv_t
    hessian = np.einsum("kaf,keb->kabef", inv_t, q) + np.einsum("kae,kfb->kabef", s, t)
    hessian = (hessian + np.einsum("kaf,keb->kabef", q, inv_t)).reshape(-1, 9, 9) + np.eye(9)
    values, vectors = np.linalg.eigh(0.5 * (hessian + hessian.transpose(0, 2, 1)))
    assert (values.min(1) < -0.1).sum() > 5  # far enough from rest for the projection to matter
    clamped = np.einsum("kij,kj,klj->kil", vectors, np.maximum(values, 1e-8) * 2 * scale[:, None], vectors)
    expected = np.einsum("kcb,kabef,kdf->kcade", b, clamped.reshape(-1, 3, 3, 3, 3), b).reshape(-1, 12, 12)
    u, sigma, vt = np.linalg.svd(jac)
    got = _element_hessians(u, sigma, vt, scale, b)
    assert np.abs(got - expected).max() <= 1e-9 * np.abs(expected).max()


def distorted(cells=3, spread=0.12, seed=3):
    """A grid, its soft-handle solver and positions far from rest with every tet positively oriented (some twist
    modes' eigenvalues negative): tets whose random push inverts them are pushed back to rest."""
    vertices, tets = grid(cells)
    solver = InjectiveSolver(vertices, tets, selection(np.arange(4), len(vertices)), 10.0)
    x = vertices + np.random.default_rng(seed).normal(0, spread, vertices.shape)
    while (bad := tet_signed_volumes(x, tets) <= 0).any():
        x[np.unique(tets[bad])] = vertices[np.unique(tets[bad])]
    return vertices, tets, solver, x


def test_compiled_svd_matches_lapack():
    """The one-sided Jacobi SVD of the Newton kernel: reconstructs the matrix, orthonormal factors, V a rotation,
    U one on positively oriented matrices, the singular values of LAPACK, also at a condition number of 1e7."""
    rng = np.random.default_rng(5)
    mild = np.eye(3) + rng.normal(0, 0.5, (500, 3, 3))
    rotations = [np.linalg.qr(rng.normal(size=(500, 3, 3)))[0] for _ in range(2)]
    stiff = rotations[0] @ (10.0 ** rng.uniform(-6, 1, (500, 3, 1)) * rotations[1])
    for matrices in (mild, stiff):
        for a in matrices:
            u, s, v = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
            _svd3(a, u, s, v)
            assert np.abs(u * s @ v.T - a).max() <= 1e-14 * np.abs(a).max()
            assert np.abs(u.T @ u - np.eye(3)).max() < 1e-14 and np.abs(v.T @ v - np.eye(3)).max() < 1e-14
            assert np.linalg.det(v) == pytest.approx(1.0) and np.linalg.det(u) == pytest.approx(
                np.sign(np.linalg.det(a))
            )
            reference = np.linalg.svd(a, compute_uv=False)
            assert np.sort(s)[::-1] == pytest.approx(reference, rel=1e-15 * reference[0] / reference[-1] + 1e-13)


def test_compiled_newton_system_and_energy_match_numpy():
    """Oracle: the Newton matrix assembled densely from the numpy eigensystem (:func:`_element_hessians` on LAPACK's
    SVD) and the gradient ``b_c · (∂E/∂J)ᵀ`` summed per vertex, plus the constraint terms, and the energy from numpy's
    ``det`` and ``inv``; far from rest, where the projection matters. Inverted positions have infinite energy."""
    vertices, tets, solver, x = distorted()
    targets = vertices[:4] + 0.1
    matrix, gradient = solver._newton_system(x, solver._soft.expand(vertices, targets))
    jac = solver.jacobians(x)
    u, sigma, vt = np.linalg.svd(jac)
    scale, b = 0.25 * solver.volumes, solver.gradient_map
    assert (
        2 - 2 * (sigma[:, 0] ** 2 - sigma[:, 0] * sigma[:, 1] + sigma[:, 1] ** 2) / (sigma[:, 0] * sigma[:, 1]) ** 3 < 0
    ).any()
    element = _element_hessians(u, sigma, vt, scale, b)
    n, c = len(vertices), solver.constraints.toarray()
    dofs = (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 12)
    expected = np.zeros((3 * n, 3 * n))
    for rows, block in zip(dofs, element):
        expected[np.ix_(rows, rows)] += block
    expected += 2 * solver.constraint_weight * np.kron(c.T @ c, np.eye(3))
    expected += np.eye(3 * n) * injective.RIDGE * np.trace(expected) / (3 * n)
    assert np.abs(matrix.toarray() - expected).max() <= 1e-10 * np.abs(expected).max()
    stress = (u * (scale[:, None] * (2 * sigma - 2 / sigma**3))[:, None, :]) @ vt
    numpy_gradient = np.zeros((n, 3))
    np.add.at(numpy_gradient, tets, b @ stress.transpose(0, 2, 1))
    numpy_gradient += 2 * solver.constraint_weight * c.T @ (c @ x - targets)
    assert np.abs(gradient - numpy_gradient.ravel()).max() <= 1e-10 * np.abs(numpy_gradient).max()
    inverse = np.linalg.inv(jac)
    distortion = np.einsum("kab,kab->k", jac, jac) + np.einsum("kab,kab->k", inverse, inverse) - 6
    penalty = c @ x - targets
    numpy_energy = 0.25 * solver.volumes @ distortion + solver.constraint_weight * np.sum(penalty**2)
    assert solver.energy(x, targets) == pytest.approx(numpy_energy, rel=1e-12)
    assert solver.energy(vertices[[0, 2, 1, *range(3, n)]], targets) == np.inf


def test_compiled_maximal_step_matches_flip_free_step_and_bisection():
    """The solver's maximal flip-free step (compiled candidates, :func:`_relative_motions`) equals
    :func:`flip_free_step` on the same edge matrices, and a bisection on the smallest tet volume along the step
    brackets it: every tet positive just before it, one flat at it."""
    _, tets, solver, x = distorted(4, 0.05, seed=7)
    rng = np.random.default_rng(8)
    for spread in (0.02, 0.2, 2.0):
        step = rng.normal(0, spread, x.shape)
        edges, directions = solver.edge_matrices(x), solver.edge_matrices(step)
        for limit in (np.inf, 1 / injective.SAFE_STEP):
            got = _first_flattening(_relative_motions(x, step, tets, limit))
            assert got == pytest.approx(flip_free_step(edges, directions, limit), rel=1e-12)
        alpha = _first_flattening(_relative_motions(x, step, tets, np.inf))
        low, high = 0.0, alpha * 1.5  # bisection oracle: the first α where a tet's volume reaches 0
        for _ in range(60):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if tet_signed_volumes(x + middle * step, tets).min() > 0 else (low, middle)
        assert alpha == pytest.approx(high, rel=1e-9)


def test_flip_free_step_is_where_the_first_tet_flattens():
    rng = np.random.default_rng(1)
    edges = np.eye(3) + rng.normal(0, 0.2, (200, 3, 3))
    edges = edges[np.linalg.det(edges) > 0]
    directions = rng.normal(0, 1.0, edges.shape)
    alpha = flip_free_step(edges, directions)
    dets = lambda a: np.linalg.det(edges + a * directions)  # noqa: E731
    assert 0 < alpha < np.inf
    assert (dets(0.999 * alpha) > 0).all() and dets(alpha).min() == pytest.approx(0, abs=1e-9)
    for a in np.linspace(0, 0.999 * alpha, 50):
        assert (dets(a) > 0).all()
    assert flip_free_step(edges, 0.1 * edges) == np.inf  # growing every tet never flattens one
    # a limit skips tets that cannot flatten before it: exact below the limit, at least the limit above it
    assert flip_free_step(edges, directions, limit=2 * alpha) == alpha
    assert flip_free_step(edges, directions, limit=0.5 * alpha) >= 0.5 * alpha
    assert flip_free_step(edges, 1e-3 * directions, limit=1.0) == np.inf


def test_a_folding_pull_stays_injective_and_lowers_the_energy():
    """Top face turned by 150° and pushed down into the box: soft ARAP folds tets (10 of 162), the solver from rest
    never does (every iterate positively oriented) and approaches the targets."""
    from nerfedit_plugin.geometry.arap import ArapSolver

    vertices, tets = grid(3)
    handles, targets = twist_targets(vertices, 1.0, degrees=150.0, shift=(0.0, 0.0, -0.5))
    constraints = selection(handles, len(vertices))
    arap = ArapSolver(vertices, tets, energy="elements", constraints=constraints, constraint_weight=1000.0)
    assert (tet_signed_volumes(arap.solve(constraint_targets=targets).vertices, tets) <= 0).any()
    solver = InjectiveSolver(vertices, tets, constraints, 1000.0)
    seen = []
    result = solver.solve(vertices, targets, max_iterations=100, stop=lambda x: seen.append(x.copy()) and False)
    assert all((tet_signed_volumes(x, tets) > 0).all() for x in seen)
    assert (np.diff(result.energies) < 0).all()
    assert np.abs(result.vertices[handles] - targets).max() < 0.05
    with pytest.raises(NerfEditError, match="inverted"):
        solver.solve(vertices[[0, 2, 1, *range(3, len(vertices))]], targets)  # swapping vertices inverts tets


def test_matches_libigl_slim():
    """Oracle: libigl's SLIM on the symmetric Dirichlet energy with soft handles ``p‖x_b − bc‖²`` minimises 4× our
    energy with ``w_c = p/4`` (plus a constant): both reach the same minimiser (a 2-unit box, so volumes are not 1)."""
    igl = pytest.importorskip("igl")
    size = 2.0
    vertices, tets = grid(3, size)
    handles, targets = twist_targets(vertices, size, degrees=45.0)
    p = 10.0
    data = igl.slim_precompute(
        np.asfortranarray(vertices),
        np.asfortranarray(tets.astype(np.int32)),
        np.asfortranarray(vertices),
        igl.MappingEnergyType.SYMMETRIC_DIRICHLET,
        handles.astype(np.int32),
        np.asfortranarray(targets),
        p,
    )
    oracle = igl.slim_solve(data, 100)
    constraints = selection(handles, len(vertices))
    unit = InjectiveSolver(vertices, tets, constraints, 1.0).constraint_weight  # w_c of w = 1
    solver = InjectiveSolver(vertices, tets, constraints, p / 4 / unit)
    ours = solver.solve(vertices, targets, max_iterations=100, tolerance=1e-12)
    assert ours.converged and (tet_signed_volumes(oracle, tets) > 0).all()
    assert solver.energy(ours.vertices, targets) <= solver.energy(oracle, targets) * (1 + 1e-9)
    assert solver.energy(oracle, targets) == pytest.approx(ours.energies[-1], rel=1e-5)
    assert np.abs(oracle - ours.vertices).max() < 1e-4 * size
