"""The multiresolution path's per-move pieces (:mod:`nerfedit_plugin.geometry.multires`) against the straightforward
computations they replace: the coarse handle targets from precomputed weights against per-cluster means and
per-cluster Umeyama fits, and the carry kernel (float64 and float32 output) against a numpy evaluation of
``Σ_c w_ic (y_k + M_k (p_i − q_k))``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.multires import MultiresArap, carry, coarse_level
from tests.deformers.test_arap_multires import bumpy_cylinder


@pytest.fixture(scope="module")
def mesh() -> SurfaceMesh:
    return bumpy_cylinder(61, 32)  # an open bumpy tube of radius 0.2 along z ∈ [0, 2]


def straightforward_targets(solver: MultiresArap, targets: np.ndarray) -> np.ndarray:
    """Per coarse handle: its vertex plus the mean displacement of its members (all handles), or, for a partly held
    cluster, plus the displacement at the coarse vertex of the similarity fitted (Umeyama) to the handles of its
    neighbourhood, each cluster fitted on its own."""
    level, rest, handles = solver.level, solver.rest.vertices, solver.handles
    coarse = level.coarse.vertices
    owner = level.owner[handles]
    out = []
    for frame in targets:
        moves = frame - rest[handles]
        rows = []
        for k in solver.fixed:
            if k not in solver._partial:
                rows.append(coarse[k] + moves[owner == k].mean(0))
                continue
            ring = {k} | {int(v) for face in level.coarse.faces if k in face for v in face}
            member = np.flatnonzero(np.isin(owner, list(ring)))
            q = rest[handles[member]] - coarse[k]
            t = q + moves[member]
            qc, tc = q - q.mean(0), t - t.mean(0)
            u, sigma, vt = np.linalg.svd(tc.T @ qc)
            flip = np.array([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
            rotation = u @ np.diag(flip) @ vt
            spread = np.linalg.eigvalsh(qc.T @ qc)
            if spread[1] > 1e-6 * spread[2]:
                scale = (sigma * flip).sum() / np.trace(qc.T @ qc)
                rows.append(coarse[k] + t.mean(0) - scale * rotation @ q.mean(0))
            else:
                rows.append(coarse[k] + t.mean(0) - q.mean(0))
        out.append(np.array(rows))
    return np.stack(out)


def test_coarse_targets_equal_the_per_cluster_fits(mesh):
    level = coarse_level(mesh, 400)
    low = {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, 0.3]}}, "fixed": True}
    turn = {"rotate": {"axis": [1, 0.3, 0], "degrees": 35, "center": [0, 0, 1.8]}, "translate": [0, 0.2, 0.1]}
    high = {"select": {"box": {"min": [-1, -1, 1.63], "max": [1, 1, 3]}}, "transform": {**turn, "scale": 1.2}}
    edit = parse_edit_spec({"handles": [low, high], "frames": 3}, ("handles",))
    handles, targets = edit.handle_targets(mesh.vertices, mesh.faces)
    solver = MultiresArap(level, mesh, handles)
    assert len(solver._partial) > 0  # the fit is exercised
    fast = solver.coarse_targets(targets)
    expected = straightforward_targets(solver, targets)
    assert fast.shape == expected.shape == (3, len(solver.fixed), 3)
    assert np.abs(fast - expected).max() < 1e-12


def test_carry_equals_the_blend_of_local_maps_in_both_precisions(mesh):
    level = coarse_level(mesh, 300)
    rng = np.random.default_rng(3)
    q = level.coarse.vertices
    moved = q + 0.05 * rng.normal(size=q.shape)
    maps = Rotation.from_rotvec(0.3 * rng.normal(size=(len(q), 3))).as_matrix() * rng.uniform(0.8, 1.2, (len(q), 1, 1))
    k, w, p = level.corners, level.weights, mesh.vertices
    expected = np.einsum("vc,vcd->vd", w, moved[k] + np.einsum("vcab,vcb->vca", maps[k], p[:, None] - q[k]))
    assert np.abs(carry(level, p, moved, maps) - expected).max() < 1e-14
    single = carry(level, p, moved, maps, np.empty((len(p), 3), dtype=np.float32))
    assert single.dtype == np.float32  # rounded once from the float64 sum
    assert np.abs(single - expected).max() <= np.spacing(np.float32(np.abs(expected).max()))
    with pytest.raises(ValueError, match="C-contiguous"):
        carry(level, p, moved, maps, np.empty((len(p), 4)))


def test_surface_into_a_buffer_places_the_handles_exactly(mesh):
    level = coarse_level(mesh, 300)
    edit = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, 0.3]}}, "fixed": True},
                {"select": {"box": {"min": [-1, -1, 1.7], "max": [1, 1, 3]}}, "transform": {"translate": [0, 0.3, 0]}},
            ]
        },
        ("handles",),
    )
    handles, targets = edit.handle_targets(mesh.vertices, mesh.faces)
    solver = MultiresArap(level, mesh, handles)
    coarse = solver.solve(solver.coarse_targets(targets)[0], max_iterations=5).vertices
    positions, gap = solver.surface(coarse, targets[0])
    buffer = np.empty((mesh.n_vertices, 3))
    into, same_gap = solver.surface(coarse, targets[0], buffer)
    assert into is buffer and np.array_equal(into, positions) and same_gap == gap
    assert np.array_equal(positions[handles], targets[0])
