"""The forward map of a DeformationField (rest → deformed, with the deformation gradient F = D' D⁻¹): identities are
identities, affine motions are reproduced with their matrix as F, the backward map undoes it, and points are located
as brute force locates them."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.locate import locate_brute_force
from nerfedit_plugin.bending.maps import BackwardMap, ForwardMap


def sample(vertices: np.ndarray, n: int, seed: int = 0, grow: float = 1.2) -> torch.Tensor:
    lo, hi = vertices.min(0), vertices.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * grow
    return torch.as_tensor(np.random.default_rng(seed).uniform(centre - half, centre + half, (n, 3)))


def bent(vertices: np.ndarray) -> np.ndarray:
    """A smooth non-rigid deformation: a bend about y growing with z, and a twist about z."""
    z = vertices[:, 2] - vertices[:, 2].min()
    angle, twist = 0.6 * z, 0.4 * z
    x, y = vertices[:, 0], vertices[:, 1]
    x, y = x * np.cos(twist) - y * np.sin(twist), x * np.sin(twist) + y * np.cos(twist)
    return np.stack([x * np.cos(angle) + z * np.sin(angle), y, -x * np.sin(angle) + z * np.cos(angle)], 1)


def test_a_deformation_field_declares_both_maps(capsule_proxy):
    field = DeformationField.identity(capsule_proxy.vertices, capsule_proxy.tets)
    assert isinstance(field, ForwardMap) and isinstance(field, BackwardMap)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_identity_is_the_identity_bit_for_bit(capsule_proxy, dtype):
    field = DeformationField.identity(capsule_proxy.vertices, capsule_proxy.tets, n_frames=2, dtype=dtype)
    x = sample(capsule_proxy.vertices, 20000).to(dtype)
    out = field.to_deformed(x, 1)
    assert 0.3 < out.inside.double().mean() < 0.9
    assert torch.equal(out.points, x) and torch.equal(out.gradient, torch.eye(3, dtype=dtype).expand(len(x), 3, 3))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_an_affine_motion_is_reproduced_with_its_matrix_as_the_gradient(capsule_proxy, dtype):
    v = capsule_proxy.vertices
    matrix = Rotation.from_rotvec([0.4, -0.3, 0.9]).as_matrix() @ np.diag([1.3, 0.8, 1.1])  # rotation and stretch
    shift = np.array([0.3, -0.2, 0.5])
    field = DeformationField(v, capsule_proxy.tets, (v @ matrix.T + shift)[None], dtype=dtype)
    x = sample(v, 20000, seed=1)
    out = field.to_deformed(x)
    inside = out.inside.numpy()
    atol = 1e-5 if dtype == torch.float32 else 1e-12
    assert inside.mean() > 0.3
    assert np.allclose(out.points.double().numpy()[inside], x.numpy()[inside] @ matrix.T + shift, atol=atol)
    assert np.allclose(out.gradient.double().numpy()[inside], matrix, atol=atol)
    assert torch.equal(out.points[~out.inside], x[~out.inside].to(dtype))  # outside T: untouched


def test_forward_then_backward_is_the_identity_and_the_jacobians_are_inverse(capsule_proxy):
    v = capsule_proxy.vertices
    field = DeformationField(v, capsule_proxy.tets, bent(v)[None], dtype=torch.float64)
    x = sample(v, 20000, seed=2, grow=0.9)
    forward = field.to_deformed(x)
    inside = forward.inside
    back = field.to_canonical(forward.points[inside])
    assert inside.double().mean() > 0.5 and back.inside.double().mean() > 0.999
    ok = back.inside
    assert torch.allclose(back.points[ok], x[inside][ok], atol=1e-9)
    product = back.jacobian[ok] @ forward.gradient[inside][ok]
    assert torch.allclose(product, torch.eye(3, dtype=torch.float64).expand_as(product), atol=1e-8)


def test_points_are_located_as_brute_force_locates_them(capsule_proxy):
    v, tets = capsule_proxy.vertices, capsule_proxy.tets
    field = DeformationField(v, tets, bent(v)[None], dtype=torch.float64)
    x = sample(v, 5000, seed=3)
    tet, bary = locate_brute_force(v, tets, x, dtype=torch.float64)
    found = tet >= 0
    assert torch.equal(field.to_deformed(x).inside, found)
    expected = (bary[found, :, None] * torch.as_tensor(bent(v))[torch.as_tensor(tets)[tet[found]]]).sum(1)
    assert torch.allclose(field.to_deformed(x).points[found], expected, atol=1e-12)
