"""``ArapSolver.solve(callback=...)``: told every energy of ``ArapResult.energies``, in order, and changes nothing."""

import numpy as np
import pytest

from nerfedit_plugin.geometry.arap import ArapSolver


@pytest.fixture(scope="module")
def bent(capsule):
    """The capsule's ARAP solver with its bottom fixed and its top moved sideways, and the top's targets."""
    z = capsule.vertices[:, 2]
    bottom, top = np.flatnonzero(z < -0.9), np.flatnonzero(z > 0.9)
    solver = ArapSolver(capsule.vertices, capsule.faces, fixed=np.concatenate([bottom, top]))
    targets = capsule.vertices[np.concatenate([bottom, top])].copy()
    targets[len(bottom) :] += [0.3, 0.0, 0.0]
    return solver, targets


@pytest.mark.parametrize("method", ["lbfgs", "anderson"])
@pytest.mark.parametrize("max_iterations", [1, 40])
def test_callback_sees_every_energy_of_the_result(bent, method, max_iterations):
    solver, targets = bent
    heard = []
    result = solver.solve(
        targets, max_iterations=max_iterations, method=method, callback=lambda k, e: heard.append((k, e))
    )
    assert heard == list(enumerate(result.energies))
    assert 1 <= result.iterations <= max_iterations
    plain = solver.solve(targets, max_iterations=max_iterations, method=method)
    assert np.array_equal(plain.vertices, result.vertices) and plain.energies == result.energies


def test_callback_of_a_solve_at_the_minimum_sees_the_one_energy(bent):
    solver, _ = bent
    heard = []
    result = solver.solve(callback=lambda k, e: heard.append((k, e)))  # the rest pose: E = 0, nothing to iterate
    assert result.iterations == 0 and heard == [(0, result.energies[0])]
