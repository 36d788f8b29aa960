"""Soft linear constraints evaluated by their expansion about a base point: the same value and gradient as the sum
over the rows, without its cost, and without the cancellation of an expansion about the origin."""

import numpy as np
import scipy.sparse as sp

from nerfedit_plugin.geometry.soft_constraints import SoftConstraints


def _barycentric(m: int, n: int, rng: np.random.Generator) -> sp.csr_matrix:
    """(m, n): each row a random convex combination of 4 columns (an embedding in tets)."""
    columns = np.array([rng.choice(n, 4, replace=False) for _ in range(m)])
    weights = rng.dirichlet(np.ones(4), m)
    return sp.csr_matrix((weights.ravel(), (np.repeat(np.arange(m), 4), columns.ravel())), shape=(m, n))


def test_value_and_gradient_equal_the_row_sums():
    rng = np.random.default_rng(0)
    matrix = _barycentric(500, 40, rng)
    soft = SoftConstraints(matrix)
    targets, base = rng.normal(size=(500, 3)), rng.normal(size=(40, 3))
    expansion = soft.expand(base, targets)
    for x in (base, base + 0.01 * rng.normal(size=base.shape), rng.normal(size=base.shape)):
        residual = matrix @ x - targets
        assert np.isclose(expansion.value(x), np.sum(residual**2), rtol=1e-12, atol=0)
        assert np.allclose(expansion.gradient(x), matrix.T @ residual, rtol=1e-12, atol=1e-12)
    assert np.isclose(expansion.value(base), np.sum((matrix @ base - targets) ** 2), rtol=1e-14, atol=0)  # d = 0


def test_exact_fit_is_summed_over_the_rows():
    rng = np.random.default_rng(1)
    matrix = _barycentric(300, 30, rng)
    solution, base = rng.normal(size=(30, 3)), rng.normal(size=(30, 3))
    expansion = SoftConstraints(matrix).expand(base, matrix @ solution)
    # the expansion cancels to rounding (relative to the base's misfit); the rows give the exact zero
    assert expansion.value(solution) == np.sum((matrix @ solution - matrix @ solution) ** 2) == 0.0
    assert np.abs(expansion.gradient(solution)).max() < 1e-12 * np.abs(matrix.T @ (matrix @ base)).max()


def test_far_targets_keep_their_digits():
    """Targets far from the origin (a scene 1e4 away): about a nearby base the small misfit keeps its digits, which an
    expansion about the origin (‖T‖² ≈ 1e11 minus almost as much) would lose."""
    rng = np.random.default_rng(2)
    matrix = _barycentric(2000, 60, rng)
    solution = 1e4 + rng.normal(size=(60, 3))
    targets = matrix @ solution + 1e-3 * rng.normal(size=(2000, 3))
    x = solution + 1e-4 * rng.normal(size=solution.shape)
    exact = np.sum((matrix @ x - targets) ** 2)
    nearby = SoftConstraints(matrix).expand(solution + 1e-3, targets).value(x)
    assert abs(nearby - exact) <= 1e-9 * exact
    soft = SoftConstraints(matrix)
    origin = np.sum(x * (soft.gram @ x)) - 2 * np.sum(x * (matrix.T @ targets)) + np.sum(targets**2)
    assert abs(origin - exact) > 1e3 * abs(nearby - exact)  # what the base point buys


def test_an_origin_shifts_the_positions_not_the_targets():
    """Centred positions with the centre as ``origin`` give the uncentred penalty; ``pulled_targets`` is
    ``Cᵀ(T − C·origin)``, the right-hand side of the centred normal equations."""
    rng = np.random.default_rng(3)
    matrix = _barycentric(400, 30, rng)
    positions, targets = rng.normal(size=(30, 3)) + 5.0, rng.normal(size=(400, 3)) + 5.0
    origin = positions.mean(0)
    centred = SoftConstraints(matrix).expand(positions - origin + 0.1, targets, origin)
    x = positions - origin
    residual = matrix @ positions - targets
    assert np.isclose(centred.value(x), np.sum(residual**2), rtol=1e-12, atol=0)
    assert np.allclose(centred.gradient(x), matrix.T @ residual, rtol=1e-12, atol=1e-12)
    expected = matrix.T @ (targets - matrix @ np.broadcast_to(origin, positions.shape))
    assert np.allclose(centred.pulled_targets, expected, rtol=1e-12, atol=1e-12)
