"""Soft linear constraints evaluated by their expansion about a base point: the same value and gradient as the sum
over the rows, without its cost, and without the cancellation of an expansion about the origin."""

import numpy as np
import pytest
import scipy.sparse as sp

from nerfedit_plugin.errors import NerfEditError
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


def test_an_exact_fit_is_zero_to_the_rows_rounding():
    """The expansion cancels at an exact fit (its rounding: ε × the base's misfit, about 1e-13 here), so it moves its
    base there: value and gradient then come from the rows, zero up to their own rounding (ε² per row)."""
    rng = np.random.default_rng(1)
    matrix = _barycentric(300, 30, rng)
    solution, base = rng.normal(size=(30, 3)), rng.normal(size=(30, 3))
    expansion = SoftConstraints(matrix).expand(base, matrix @ solution)
    assert expansion.value(base) > 1e2
    assert 0.0 <= expansion.value(solution) < 1e-27
    assert np.abs(expansion.gradient(solution)).max() < 1e-14


def test_a_falling_misfit_keeps_its_digits():
    """Iterates converging on a least-squares fit over 12 decades of the misfit: every value within 1e-10 of the row
    sum, relative (the base moves each time the expansion would lose more than 4 digits)."""
    rng = np.random.default_rng(4)
    matrix = _barycentric(3000, 50, rng)
    targets = matrix @ rng.normal(size=(50, 3)) + 1e-3 * rng.normal(size=(3000, 3))
    fit = np.linalg.lstsq(matrix.toarray(), targets, rcond=None)[0]
    direction = rng.normal(size=fit.shape)
    expansion = SoftConstraints(matrix).expand(fit + direction, targets)
    for k in range(13):
        x = fit + 10.0 ** (-k) * direction
        exact = np.sum((matrix @ x - targets) ** 2)
        assert abs(expansion.value(x) - exact) <= 1e-10 * exact
        assert np.allclose(expansion.gradient(x), matrix.T @ (matrix @ x - targets), rtol=0, atol=1e-9)


def test_wrong_shapes_name_the_array():
    soft = SoftConstraints(_barycentric(20, 10, np.random.default_rng(5)))
    with pytest.raises(NerfEditError, match=r"targets must have shape \(20, 3\), got \(4, 3\)"):
        soft.expand(np.zeros((10, 3)), np.zeros((4, 3)))
    with pytest.raises(NerfEditError, match=r"positions must have shape \(10, 3\)"):
        soft.expand(np.zeros((10, 2)), np.zeros((20, 3)))
    with pytest.raises(NerfEditError, match="origin"):
        soft.expand(np.zeros((10, 3)), np.zeros((20, 3)), np.zeros(2))


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
