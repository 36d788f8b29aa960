"""LBS and DQS: identity, exact rigid motion, libigl's LBS as an oracle, DQS sign invariance, the candy wrapper."""

import igl
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deformers.skeleton.skinning import Binding, dqs, dual_quaternions, lbs, normalize_weights, skin

RNG = np.random.default_rng(7)
POINTS = RNG.uniform(-1, 1, (300, 3))
WEIGHTS = normalize_weights(RNG.random((300, 5)) ** 4)


def random_bones(n, seed=0):
    rot = Rotation.random(n, random_state=seed).as_matrix()
    return rot, np.random.default_rng(seed).normal(size=(n, 3))


def cylinder_points(rings=41, sides=16, radius=0.25):
    """Rings along z ∈ [-1, 1] (one exactly at z = 0)."""
    z = np.linspace(-1, 1, rings)
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    return np.column_stack(
        [np.tile(radius * np.cos(a), rings), np.tile(radius * np.sin(a), rings), np.repeat(z, sides)]
    )


@pytest.mark.parametrize("method", ["dqs", "lbs"])
def test_identity_bones_give_identity(method):
    out = skin(Binding.create(POINTS, WEIGHTS), np.tile(np.eye(3), (5, 1, 1)), np.zeros((5, 3)), method)
    assert np.abs(out - POINTS).max() < 1e-14


@pytest.mark.parametrize("method", ["dqs", "lbs"])
def test_shared_rigid_transform_moves_points_rigidly(method):
    rot, trans = random_bones(1, seed=3)
    out = skin(Binding.create(POINTS, WEIGHTS), np.repeat(rot, 5, 0), np.repeat(trans, 5, 0), method)
    assert np.abs(out - (POINTS @ rot[0].T + trans[0])).max() < 1e-12


def test_one_hot_weights_apply_each_bone_exactly():
    rot, trans = random_bones(5, seed=4)
    owner = RNG.integers(0, 5, len(POINTS))
    binding = Binding.create(POINTS, np.eye(5)[owner])
    expected = np.einsum("nij,nj->ni", rot[owner], POINTS) + trans[owner]
    assert np.abs(dqs(binding, dual_quaternions(rot, trans)) - expected).max() < 1e-12
    assert np.abs(lbs(binding, rot, trans) - expected).max() < 1e-12


def test_lbs_matches_libigl_lbs_matrix():
    rot, trans = random_bones(5, seed=5)
    # libigl: V' = M T, T stacks the transposed 3×4 matrices [R | t] of the bones.
    stacked = np.concatenate([np.concatenate([r.T, t[None]], 0) for r, t in zip(rot, trans)], 0)
    expected = igl.lbs_matrix(POINTS, WEIGHTS) @ np.ascontiguousarray(stacked)
    assert np.abs(lbs(Binding.create(POINTS, WEIGHTS), rot, trans) - expected).max() < 1e-12


def test_dqs_is_sign_invariant():
    rot, trans = random_bones(5, seed=6)
    dq = dual_quaternions(rot, trans)
    assert (dq[:, :4] @ dq[:, :4].T < 0).any()  # some bones start in opposite hemispheres
    binding = Binding.create(POINTS, WEIGHTS)
    base = dqs(binding, dq)
    for j in range(5):
        flipped = dq.copy()
        flipped[j] *= -1
        assert np.abs(dqs(binding, flipped) - base).max() < 1e-12
    assert np.abs(dqs(binding, -dq) - base).max() < 1e-12


def test_dqs_blend_is_rigid_per_point():
    """Every point's blended dual quaternion is a rigid map: distances between a point's two images are kept."""
    rot, trans = random_bones(5, seed=8)
    dq = dual_quaternions(rot, trans)
    offset = np.array([1e-3, -2e-3, 0.5e-3])
    a = dqs(Binding.create(POINTS, WEIGHTS), dq)
    b = dqs(Binding.create(POINTS + offset, WEIGHTS), dq)  # same weights, so the same rigid map per point
    assert np.abs(np.linalg.norm(a - b, axis=1) - np.linalg.norm(offset)).max() < 1e-12


def test_candy_wrapper_twist():
    """A 180° twist of the upper bone: DQS keeps every ring's radius, LBS collapses the middle ring to the axis."""
    points = cylinder_points()
    w1 = np.clip(points[:, 2] + 0.5, 0.0, 1.0)  # 0 below z=-0.5, 1 above z=0.5, 1/2 at z=0
    binding = Binding.create(points, np.column_stack([1 - w1, w1]))
    rot = np.stack([np.eye(3), Rotation.from_rotvec([0, 0, np.pi]).as_matrix()])
    trans = np.zeros((2, 3))
    radius = lambda x: np.linalg.norm(x[:, :2], axis=1)  # noqa: E731
    middle = np.abs(points[:, 2]) < 1e-12
    assert middle.sum() == 16
    out_dqs = skin(binding, rot, trans, "dqs")
    assert np.abs(radius(out_dqs) - 0.25).max() < 1e-12
    assert np.abs(out_dqs[:, 2] - points[:, 2]).max() < 1e-12
    out_lbs = skin(binding, rot, trans, "lbs")
    assert radius(out_lbs)[middle].max() < 1e-12
    assert radius(out_lbs)[~middle].min() > 0


def test_normalize_weights_threshold_keeps_the_largest_and_sums_to_one():
    w = np.array([[0.5, 0.004, 0.496], [0.001, 0.0005, 0.0002], [-0.1, 1.0, 0.2]])
    out = normalize_weights(w, threshold=0.01)
    assert np.allclose(out.sum(1), 1.0)
    assert out[0, 1] == 0 and out[0, 0] > 0.5
    assert np.array_equal(out[1], [1.0, 0.0, 0.0])  # all below threshold: the largest survives
    assert out[2, 0] == 0 and np.isclose(out[2, 1], 1 / 1.2)


def test_binding_groups_points_by_dominant_bone():
    binding = Binding.create(POINTS, WEIGHTS)
    assert np.array_equal(np.sort(np.concatenate(binding.dominated)), np.arange(len(POINTS)))
    for k, rows in enumerate(binding.dominated):
        assert (WEIGHTS[rows].argmax(1) == k).all()


def quat_mul(p, q):
    """Hamilton product of quaternions (w, x, y, z)."""
    pw, pv, qw, qv = p[0], np.asarray(p[1:]), q[0], np.asarray(q[1:])
    return np.concatenate([[pw * qw - pv @ qv], pw * qv + qw * pv + np.cross(pv, qv)])


def hand_dqs(points, weights, duals, align):
    """DQS point by point from docs/method.md: flip each bone's dual quaternion (J,8) to agree with bone
    ``align[n]`` of point n, blend with the point's weights, divide by the real part's norm, and apply the unit dual
    quaternion q + ε q_ε as the rotation of q (scipy) plus the translation 2 q_ε q* (the vector part)."""
    out = np.empty_like(points)
    for n, (x, w) in enumerate(zip(points, weights)):
        reference = duals[align[n], :4]
        blend = sum(w_j * np.sign(dq[:4] @ reference) * dq for w_j, dq in zip(w, duals))
        real, dual = blend[:4] / np.linalg.norm(blend[:4]), blend[4:] / np.linalg.norm(blend[:4])
        translation = 2.0 * quat_mul(dual, real * [1, -1, -1, -1])[1:]
        out[n] = Rotation.from_quat(np.roll(real, -1)).apply(x) + translation
    return out


def test_dqs_aligns_signs_with_each_points_dominant_bone():
    """Three bones whose rotation quaternions are pairwise in opposite hemispheres (half-angles 0°, 120°, 240° about
    one axis: every pair has real-part dot product −1/2), so no sign choice puts all three in one hemisphere and the
    blend depends on which bone the signs agree with: each point's dominant (largest-weight) bone."""
    axis = np.array([1.0, -2.0, 2.0]) / 3.0
    quats = np.array([np.concatenate([[np.cos(a)], np.sin(a) * axis]) for a in np.radians([0.0, 120.0, 240.0])])
    assert np.allclose(quats @ quats.T, np.where(np.eye(3, dtype=bool), 1.0, -0.5))
    rot = Rotation.from_quat(np.roll(quats, -1, axis=1)).as_matrix()  # scipy takes (x, y, z, w)
    trans = np.array([[0.5, -0.2, 0.1], [-0.3, 0.8, 0.4], [0.2, 0.1, -0.9]])
    weights = np.array([[0.5, 0.3, 0.2], [0.2, 0.5, 0.3], [0.3, 0.2, 0.5], [0.1, 0.6, 0.3], [0.35, 0.25, 0.4]])
    weights = np.repeat(weights, 4, axis=0)
    points = np.random.default_rng(11).uniform(-1, 1, (len(weights), 3))
    # the bones' dual quaternions by hand, q_ε = ½ (0, t) q, with arbitrary signs (DQS must not depend on them)
    duals = np.array(
        [
            s * np.concatenate([q, 0.5 * quat_mul(np.concatenate([[0.0], t]), q)])
            for s, q, t in zip([1, -1, 1], quats, trans)
        ]
    )
    dominant = weights.argmax(1)
    expected = hand_dqs(points, weights, duals, dominant)
    binding = Binding.create(points, weights)
    np.testing.assert_allclose(dqs(binding, duals), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(skin(binding, rot, trans, "dqs"), expected, rtol=0, atol=1e-12)
    # the choice matters: signs aligned with bone 0 would move every point that bone 1 or 2 dominates elsewhere
    to_bone_0 = hand_dqs(points, weights, duals, np.zeros(len(points), dtype=int))
    gap = np.linalg.norm(to_bone_0 - expected, axis=1)
    assert set(dominant) == {0, 1, 2} and (gap[dominant > 0] > 0.1).all() and (gap[dominant == 0] < 1e-12).all()


def test_normalize_weights_by_hand():
    """Negatives clip to 0 (no threshold by default), a weight equal to the threshold is kept, float32 → float64."""
    out = normalize_weights(np.array([[-0.5, 1.0, 0.5], [0.3, 0.7, 0.0]], dtype=np.float32))
    assert out.dtype == np.float64
    np.testing.assert_allclose(out, [[0.0, 2 / 3, 1 / 3], [0.3, 0.7, 0.0]], rtol=1e-7)
    np.testing.assert_array_equal(normalize_weights(np.array([[0.25, 0.75]]), threshold=0.25), [[0.25, 0.75]])
    # clipped before thresholding: not even a negative threshold lets a negative weight through
    np.testing.assert_array_equal(normalize_weights(np.array([[-0.5, 1.0]]), threshold=-1.0), [[0.0, 1.0]])


def test_binding_is_float64_with_sorted_dominated_points():
    binding = Binding.create(POINTS.astype(np.float32), WEIGHTS.astype(np.float32))
    assert binding.points_t.dtype == binding.weights_t.dtype == np.float64
    dominant = WEIGHTS.argmax(1)
    for k, rows in enumerate(binding.dominated):  # the brute-force grouping, in increasing point order
        np.testing.assert_array_equal(rows, np.flatnonzero(dominant == k))


def test_skin_defaults_to_dqs_and_rejects_unknown_methods():
    rot, trans = random_bones(5, seed=9)
    binding = Binding.create(POINTS, WEIGHTS)
    np.testing.assert_array_equal(skin(binding, rot, trans), dqs(binding, dual_quaternions(rot, trans)))
    with pytest.raises(ValueError, match="unknown skinning method 'slerp'"):
        skin(binding, rot, trans, "slerp")


def test_dqs_hemisphere_test_uses_the_rotations_only():
    """Two bones about z with half-angles 10° and 95° (real parts' dot cos 85° > 0: the same hemisphere) and large
    opposite translations along z, whose dual scalar parts have a large negative product: the blend keeps both
    signs, as the point-by-point DQS does."""
    quats = np.array([[np.cos(a), 0.0, 0.0, np.sin(a)] for a in np.radians([10.0, 95.0])])
    trans = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, -3.0]])
    duals = np.array([np.concatenate([q, 0.5 * quat_mul(np.concatenate([[0.0], t]), q)]) for q, t in zip(quats, trans)])
    assert duals[0, :4] @ duals[1, :4] > 0 > duals[0, :5] @ duals[1, :5]
    points = POINTS[:20]
    weights = np.tile([0.6, 0.4], (len(points), 1))
    expected = hand_dqs(points, weights, duals, np.zeros(len(points), dtype=int))
    np.testing.assert_allclose(dqs(Binding.create(points, weights), duals), expected, rtol=0, atol=1e-12)
