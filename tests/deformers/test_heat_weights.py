"""Bone-heat weights: the discrete operators against libigl, the heat equation itself, partition of unity,
non-negativity, locality, symmetry, visibility and the fallbacks for blind components and degenerate input."""

import igl
import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.spatial import cKDTree

from deformers.skeleton.heat_weights import (
    bone_heat_weights,
    closest_on_segments,
    cotangent_stiffness,
    heat_sources,
    lumped_mass,
)

TWO_BONES = (np.array([[0, 0, -0.8], [0, 0, 0]]), np.array([[0, 0, 0], [0, 0, 0.8]]))  # inside tube()


def tube(radius=0.25, length=2.0, rings=41, sides=24, x=0.0):
    """Closed tube along z with a vertex ring every length/(rings-1) (one ring at z = 0)."""
    z = np.linspace(-length / 2, length / 2, rings)
    profile = np.array([[0, z[0]], *[[radius, zz] for zz in z], [0, z[-1]]])
    mesh = trimesh.creation.revolve(profile, sections=sides)
    return np.asarray(mesh.vertices) + [x, 0, 0], np.asarray(mesh.faces)


def test_operators_match_libigl():
    v, f = tube()
    v = v + np.random.default_rng(0).normal(scale=0.01, size=v.shape)  # obtuse angles, negative cotangents
    assert np.abs(cotangent_stiffness(v, f) + igl.cotmatrix(v, f)).max() < 1e-10
    mass = igl.massmatrix(v, f, igl.MASSMATRIX_TYPE_BARYCENTRIC).diagonal()
    assert np.abs(lumped_mass(v, f) - mass).max() < 1e-15


def test_weights_solve_the_heat_equation():
    v, f = tube()
    heads, tails = TWO_BONES
    w = bone_heat_weights(v, f, heads, tails, visibility=False)
    _, dist = closest_on_segments(v, heads, tails)
    p, d = heat_sources(dist, np.ones(dist.shape, bool), 1)
    mh = sp.diags(lumped_mass(v, f) * np.count_nonzero(p, axis=1) / d**2)
    residual = (cotangent_stiffness(v, f) + mh) @ w - mh @ p
    assert np.abs(residual).max() < 1e-10 * np.abs(mh @ p).max()


def test_tube_weights_are_a_local_symmetric_partition_of_unity():
    v, f = tube()
    w = bone_heat_weights(v, f, *TWO_BONES)
    assert w.shape == (len(v), 2) and (w >= 0).all()
    assert np.abs(w.sum(1) - 1).max() < 1e-12
    assert (w[v[:, 2] < -0.6, 0] > 0.9).all() and (w[v[:, 2] > 0.6, 1] > 0.9).all()
    middle = np.abs(v[:, 2]) < 1e-9  # equidistant from both bones: shared heat, equal weights
    assert np.abs(w[middle] - 0.5).max() < 1e-9
    _, mirror = cKDTree(v).query(v * [1, 1, -1])
    assert np.abs(w[:, 0] - w[mirror, 1]).max() < 1e-9
    ring_means = [w[np.isclose(v[:, 2], z), 0].mean() for z in np.unique(v[:, 2].round(9))]
    assert (np.diff(ring_means) < 0).all()  # bone 0's weight falls monotonically along the tube


def test_one_bone_weights_are_one():
    v, f = tube()
    assert np.array_equal(bone_heat_weights(v, f, [[0, 0, -1]], [[0, 0, 1]]), np.ones((len(v), 1)))


def test_visibility_stops_heat_through_empty_space():
    """A thick tube beside a thin one: the thin tube's bone is the nearest bone of the thick tube's inner side, but
    it is not visible from there, so with visibility each tube is skinned to its own bone alone."""
    thick_v, thick_f = tube(radius=0.5, rings=11, sides=32)
    thin_v, thin_f = tube(radius=0.1, rings=11, sides=12, x=0.65)
    v, f = np.concatenate([thick_v, thin_v]), np.concatenate([thick_f, thin_f + len(thick_v)])
    heads, tails = np.array([[0, 0, -0.8], [0.65, 0, -0.8]]), np.array([[0, 0, 0.8], [0.65, 0, 0.8]])
    owner = np.repeat([0, 1], [len(thick_v), len(thin_v)])
    assert np.array_equal(bone_heat_weights(v, f, heads, tails), np.eye(2)[owner])
    blind = bone_heat_weights(v, f, heads, tails, visibility=False)
    assert blind[: len(thick_v), 1].max() > 0.5


def test_component_that_sees_no_bone_falls_back_to_nearest_bones():
    a_v, a_f = tube(rings=11)
    b_v, b_f = tube(rings=11, x=1.0)  # no bone inside: every segment to a bone crosses tube A
    v, f = np.concatenate([a_v, b_v]), np.concatenate([a_f, b_f + len(a_v)])
    w = bone_heat_weights(v, f, *TWO_BONES)
    assert np.isfinite(w).all() and np.abs(w.sum(1) - 1).max() < 1e-12
    alone = bone_heat_weights(b_v, b_f, *TWO_BONES, visibility=False)
    assert np.abs(w[len(a_v) :] - alone).max() < 1e-10
    assert (alone[b_v[:, 2] < -0.5, 0] > 0.5).all() and (alone[b_v[:, 2] > 0.5, 1] > 0.5).all()


def test_degenerate_faces_and_unreferenced_vertices():
    v, f = tube(rings=11)
    n = len(v)
    v = np.concatenate([v, [[0.0, 0.0, 0.7], v[5]]])  # one unreferenced (next to bone 1), one copy of vertex 5
    f = np.concatenate([f, [[0, 0, 1], [2, 3, 2], [5, n + 1, 5]]])  # zero-area triangles; n+1 is in no other face
    w = bone_heat_weights(v, f, *TWO_BONES)
    assert np.isfinite(w).all() and np.abs(w.sum(1) - 1).max() < 1e-12
    assert np.array_equal(w[n], [0.0, 1.0])


def test_heat_sources_k_nearest_and_ties():
    dist = np.array([[1.0, 2.0, 3.0], [2.0, 2.0, 3.0], [3.0, 1.0, 2.0]])
    allowed = np.array([[True, True, True], [True, True, True], [True, False, True]])
    p, d = heat_sources(dist, allowed, 1)
    assert np.array_equal(p, [[1, 0, 0], [0.5, 0.5, 0], [0, 0, 1]]) and np.array_equal(d, [1, 2, 2])
    p2, _ = heat_sources(dist, allowed, 2)
    assert np.array_equal(p2, [[0.5, 0.5, 0], [0.5, 0.5, 0], [0.5, 0, 0.5]])
    none, far = heat_sources(dist, np.zeros_like(allowed), 1)
    assert not none.any() and np.isinf(far).all()


def test_closest_on_segments_including_point_bones():
    heads, tails = np.array([[0, 0, 0], [1, 1, 1.0]]), np.array([[0, 0, 1], [1, 1, 1.0]])  # a segment, a point
    closest, dist = closest_on_segments(np.array([[1.0, 0, 2], [0, 0, -3]]), heads, tails)
    assert np.allclose(closest[0, 0], [0, 0, 1]) and np.isclose(dist[0, 0], np.sqrt(2))
    assert np.allclose(closest[1, 0], [0, 0, 0]) and np.isclose(dist[1, 1], np.linalg.norm([1, 1, 4]))
