"""The forward map of a splat model: SH rotation by Wigner matrices (gsplat's SH and Open3D's rotate as oracles),
identity, rigid and affine motions against their analytic ground truth, composition, inverted tets, rendering
equivalence of a rigid motion seen from the moved camera, and the split of stretched Gaussians."""

import numpy as np
import pytest
import scipy.linalg
import torch
from gsplat.cuda._torch_impl import _spherical_harmonics
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.fields.splats.deform import MAX_CHILDREN, deform_model, polar_rotations
from nerfedit_plugin.fields.splats.field import SplatsField
from nerfedit_plugin.fields.splats.files import read_ply, write_ply
from nerfedit_plugin.fields.splats.model import SplatModel, synthetic_model
from nerfedit_plugin.fields.splats.projection import covariances
from nerfedit_plugin.fields.splats.sh_rotation import rotate_sh, wigner_matrices
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets
from nerfedit_plugin.render.renderer import RenderConfig

TURN = Rotation.from_rotvec([0.4, -0.7, 0.5]).as_matrix()


def grid(half: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    vertices, tets = kuhn_grid(3, np.full(3, -half), np.full(3, half))
    return vertices, orient_tets(vertices, tets)


def affine_field(matrix: np.ndarray, shift=(0.0, 0.0, 0.0), half: float = 1.0, dtype=torch.float64):
    """The proxy of a cube of side ``2 half`` moved by ``x ↦ matrix x + shift``."""
    vertices, tets = grid(half)
    return DeformationField(vertices, tets, (vertices @ matrix.T + np.asarray(shift))[None], dtype=dtype)


def covariance(model: SplatModel) -> np.ndarray:
    quats, scales = (torch.from_numpy(a).double() for a in (model.quats, model.log_scales))
    return covariances(quats, scales).numpy()


def band_rotation(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    return rotate_sh(torch.from_numpy(sh).double(), torch.from_numpy(rotation).expand(len(sh), 3, 3)).numpy()


def test_rotated_coefficients_show_the_same_colour_along_rotated_directions():
    """Brute force with gsplat's SH (an independent basis): c'(R d) = c(d) over random directions, every band."""
    rng = np.random.default_rng(0)
    sh = torch.from_numpy(rng.normal(size=(64, 16, 3)))
    rotations = torch.from_numpy(Rotation.random(64, random_state=1).as_matrix())
    rotated = rotate_sh(sh, rotations)
    directions = torch.nn.functional.normalize(torch.from_numpy(rng.normal(size=(64, 3))), dim=-1)
    moved = (rotations @ directions[:, :, None]).squeeze(-1)
    for degree in range(4):
        k = (degree + 1) ** 2
        before = _spherical_harmonics(degree, directions, sh[:, :k])
        after = _spherical_harmonics(degree, moved, rotated[:, :k])
        assert torch.allclose(before, after, atol=1e-12)
    assert torch.equal(rotated[:, 0], sh[:, 0])  # band 0 is invariant


def test_wigner_matrices_are_an_orthogonal_representation():
    """M(R₁R₂) = M(R₁)M(R₂), M(I) = I, M(Rᵀ) = M(R)ᵀ: two rotations composed are one rotation."""
    r1, r2 = (torch.from_numpy(Rotation.random(16, random_state=s).as_matrix()) for s in (2, 3))
    for a, b, ab, eye, back in zip(
        wigner_matrices(r1, 3),
        wigner_matrices(r2, 3),
        wigner_matrices(r1 @ r2, 3),
        wigner_matrices(torch.eye(3, dtype=torch.float64)[None], 3),
        wigner_matrices(r1.transpose(1, 2), 3),
    ):
        assert torch.allclose(a @ b, ab, atol=1e-12)
        assert torch.allclose(eye[0], torch.eye(len(eye[0]), dtype=torch.float64), atol=1e-15)
        assert torch.allclose(back, a.transpose(1, 2), atol=1e-12)


def test_a_rigid_edit_matches_open3d_rotate(tmp_path):
    """Open3D 0.20's ``t.geometry.PointCloud.rotate`` of the same PLY: positions, quaternions and scales as ours. Its
    f_rest are rotated in the real SH basis without the Condon–Shortley phase ``(−1)^m`` of 3DGS's basis, after a
    scaling per coefficient (what its rotation by the identity does: |m| = 2, 3 scaled by √2, 2); given coefficients
    in its basis with that scaling undone beforehand, its bands 1–3 equal ours."""
    o3d = pytest.importorskip("open3d")
    model = synthetic_model(300, 3, seed=2, radius=0.6, dtype=np.float64)
    center = np.array([0.1, 0.0, -0.2])
    ours, report = deform_model(model, affine_field(TURN, center - TURN @ center))
    assert report.moved == len(model) and report.inverted == 0

    def open3d_rotate(sh: np.ndarray, rotation: np.ndarray) -> SplatModel:
        write_ply(SplatModel(model.means, model.quats, model.log_scales, model.opacities, sh), tmp_path / "in.ply")
        cloud = o3d.t.io.read_point_cloud(str(tmp_path / "in.ply"))
        cloud.rotate(o3d.core.Tensor(rotation), o3d.core.Tensor(center))
        o3d.t.io.write_point_cloud(str(tmp_path / "out.ply"), cloud)
        return read_ply(tmp_path / "out.ply")

    probe = np.zeros((16, 16, 3))
    probe[:, :, 0] = np.eye(16)  # Open3D's rotation by the identity, coefficient by coefficient
    scaling = open3d_rotate(np.resize(probe, (len(model), 16, 3)), np.eye(3)).sh[:16, :, 0]
    assert np.allclose(scaling, np.diag(np.diag(scaling)), atol=1e-6)  # a diagonal scaling only
    sign = np.ones(16)
    for band in range(1, 4):
        sign[band * band : (band + 1) ** 2] = [(-1.0) ** m for m in range(-band, band + 1)]
    theirs = open3d_rotate(model.sh * (sign / np.diag(scaling))[:, None], TURN)
    assert np.allclose(theirs.means, ours.means, atol=1e-6)
    quats = theirs.quats / np.linalg.norm(theirs.quats, axis=1, keepdims=True)
    assert np.allclose(quats * np.sign(quats[:, :1]), ours.quats, atol=1e-6)
    assert np.allclose(theirs.log_scales, ours.log_scales, atol=1e-6)
    assert np.allclose(theirs.sh * sign[:, None], ours.sh, atol=2e-5)


def test_the_identity_is_the_identity_bit_for_bit():
    model = synthetic_model(500, 3, seed=1)
    vertices, tets = grid()
    out, report = deform_model(model, DeformationField.identity(vertices, tets, n_frames=2), 1)
    assert report.moved == 0 and report.gaussians == 500
    for a, b in zip(out.arrays(), model.arrays()):
        assert a.dtype == b.dtype and np.array_equal(a, b)


def test_an_affine_map_moves_means_covariances_and_colours_as_its_matrix_does():
    """F = A (rotation, stretch and shear): μ' = Aμ + b, Σ' = AΣAᵀ, SH rotated by the polar rotation of A (scipy's
    polar decomposition), opacity kept; Gaussians outside the proxy untouched."""
    matrix = TURN @ np.array([[1.4, 0.3, 0.0], [0.0, 0.8, 0.25], [0.1, 0.0, 1.2]])
    shift = np.array([0.2, -0.1, 0.3])
    model = synthetic_model(2000, 3, seed=3, radius=0.9, dtype=np.float64)
    out, report = deform_model(model, affine_field(matrix, shift, half=0.7))
    inside = np.all(np.abs(model.means) < 0.7, axis=1)
    assert 0.3 < inside.mean() < 0.9 and report.moved == inside.sum() and report.inverted == 0
    assert np.allclose(out.means[inside], model.means[inside] @ matrix.T + shift, atol=1e-12)
    assert np.allclose(covariance(out)[inside], matrix @ covariance(model)[inside] @ matrix.T, atol=1e-12)
    polar = scipy.linalg.polar(matrix)[0]
    assert np.allclose(out.sh[inside], band_rotation(model.sh[inside], polar), atol=1e-12)
    assert np.array_equal(out.opacities, model.opacities)
    assert np.allclose(np.linalg.norm(out.quats[inside], axis=1), 1.0)
    for a, b in zip(out.arrays(), model.arrays()):
        assert np.array_equal(a[~inside], b[~inside])
    assert report.growth["max"] > 1.2  # the shear makes Gaussians more anisotropic


def test_a_rigid_map_keeps_the_scales_and_composes():
    """A rotation turns the quaternion (R q) and keeps the scales; two rigid edits in turn are their product."""
    model = synthetic_model(400, 3, seed=4, radius=0.6, dtype=np.float64)
    second = Rotation.from_rotvec([-0.2, 0.9, 0.1]).as_matrix()
    once, _ = deform_model(model, affine_field(TURN))
    assert np.allclose(once.log_scales, model.log_scales, atol=1e-12)
    turned = Rotation.from_matrix(TURN) * Rotation.from_quat(model.quats[:, [1, 2, 3, 0]])
    expected = turned.as_quat()[:, [3, 0, 1, 2]]
    assert np.allclose(once.quats, expected * np.sign(expected[:, :1]), atol=1e-10)
    twice, _ = deform_model(once, affine_field(second, half=1.5))
    product, _ = deform_model(model, affine_field(second @ TURN))
    assert np.allclose(twice.means, product.means, atol=1e-12)
    assert np.allclose(covariance(twice), covariance(product), atol=1e-12)
    assert np.allclose(twice.sh, product.sh, atol=1e-12)


def test_inverted_tets_take_the_nearest_rotation_and_are_counted():
    """F = diag(−1.5, 1, 0.7) mirrors x: Σ' = FΣFᵀ stays exact, the colour turns by the rotation nearest F (the
    reflection across the axis of the smallest singular value, z, removed: a half turn about y)."""
    matrix = np.diag([-1.5, 1.0, 0.7])
    rotation, inverted = polar_rotations(torch.from_numpy(matrix)[None])
    assert bool(inverted[0]) and np.allclose(rotation[0].numpy(), np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
    model = synthetic_model(300, 3, seed=5, radius=0.6, dtype=np.float64)
    vertices, tets = grid()
    field = DeformationField(vertices, tets, (vertices @ matrix.T)[None], dtype=torch.float64)
    out, report = deform_model(model, field)
    assert report.inverted == report.moved == len(model)
    assert np.allclose(covariance(out), matrix @ covariance(model) @ matrix.T, atol=1e-12)
    assert np.allclose(out.sh, band_rotation(model.sh, np.diag([-1.0, 1.0, -1.0])), atol=1e-12)


def test_a_rigidly_moved_model_seen_from_the_moved_camera_renders_as_the_rest():
    """Degree-3 colours included: the view-dependent colour turns with the model, so the moved model, seen from the
    camera moved the same way, is the rest image."""
    model = synthetic_model(1500, 3, seed=6, radius=0.6, scale=(0.02, 0.08))
    model.sh[:, 1:] *= 4.0  # strongly view-dependent colour
    shift = np.array([0.3, -0.2, 0.1])
    field = SplatsField.from_model(model)
    eye, target = torch.tensor([[1.8, 1.2, 0.9]]), torch.zeros(1, 3)
    rest = field.render(Cameras.from_fov(look_at(eye, target), 48, 48, 0.9), 0, RenderConfig())
    motion = torch.eye(4, dtype=torch.float64)
    motion[:3, :3], motion[:3, 3] = torch.from_numpy(TURN), torch.from_numpy(shift)
    moved_camera = Cameras.from_fov((motion @ look_at(eye, target).double()).float(), 48, 48, 0.9)
    moved = field.render(moved_camera, 0, RenderConfig(), deformation=affine_field(TURN, shift, dtype=torch.float32))
    unrotated = SplatsField.from_model(
        SplatModel(*deform_model(model, affine_field(TURN, shift))[0].arrays()[:4], model.sh)
    ).render(moved_camera, 0, RenderConfig())
    assert float((rest - 1.0).abs().mean()) > 0.1  # the model fills the view
    assert float((moved - rest).abs().max()) < 2e-3
    assert float((unrotated - rest).abs().max()) > 0.1  # without the SH rotation the colours are wrong


@pytest.mark.parametrize("stretch", [1.5, 3.0, 6.0, 40.0])
def test_stretched_gaussians_split_into_children_with_the_parent_moments(stretch):
    """F = diag(stretch, 1, 1) on round Gaussians: the anisotropy grows by ``stretch``; above ``split_growth`` = 2
    the children's equal mixture keeps the parent's mean and covariance, and (up to MAX_CHILDREN) each child's
    growth is within the limit."""
    model = SplatModel(
        np.array([[0.1, 0.2, -0.1]]),
        np.array([[0.9, 0.1, -0.3, 0.2]]),
        np.log(np.array([[0.05, 0.05, 0.05]])),
        np.array([0.5]),
        np.random.default_rng(7).normal(size=(1, 16, 3)),
    )
    field = affine_field(np.diag([stretch, 1.0, 1.0]))
    plain, _ = deform_model(model, field)
    out, report = deform_model(model, field, split_growth=2.0)
    assert report.growth["max"] == pytest.approx(stretch)
    k = len(out)
    assert k == (1 if stretch <= 2.0 else min(int(np.ceil(np.sqrt(2.0) * stretch / 2.0)), MAX_CHILDREN))
    assert report.split == (k > 1) and report.children == k - 1
    assert np.allclose(out.means.mean(0), plain.means[0], atol=1e-12)
    offsets = out.means - plain.means[0]
    mixture = covariance(out).mean(0) + offsets.T @ offsets / k
    assert np.allclose(mixture, covariance(plain)[0], atol=1e-12)
    scales = np.exp(out.log_scales)
    assert np.all(scales.max(1) / scales.min(1) <= max(2.0, stretch * np.sqrt(2.0) / MAX_CHILDREN) + 1e-9)
    assert np.array_equal(out.opacities, np.full(k, 0.5)) and np.allclose(out.sh, plain.sh[[0] * k])


def test_the_compiled_pass_is_the_torch_reference():
    """A bend, a shear and a mirror over a 6³ grid (thousands of distinct gradients, every tet inverted), splitting:
    the compiled pass (polar rotations and Wigner matrices per distinct F) equals the per-Gaussian torch path."""
    vertices, tets = kuhn_grid(6, np.full(3, -1.0), np.full(3, 1.0))
    z = vertices[:, 2] + 1
    bent = np.stack(
        [vertices[:, 0] * np.cos(0.4 * z) + 0.3 * z * np.sin(0.4 * z) - 0.2 * vertices[:, 1],
         vertices[:, 1] * (1 + 0.2 * z), -vertices[:, 2]], 1,
    )  # fmt: skip
    field = DeformationField(vertices, orient_tets(vertices, tets), bent[None])
    for dtype, atol in ((np.float32, 0.0), (np.float64, 1e-12)):
        model = synthetic_model(3000, 3, seed=9, radius=1.0, dtype=dtype)
        reference, expected = deform_model(model, field, split_growth=1.5, kernel="torch")
        compiled, report = deform_model(model, field, split_growth=1.5)
        assert report.moved == report.inverted == len(compiled) and report.split == expected.split > 0
        for a, b in zip(compiled.arrays(), reference.arrays()):
            assert a.dtype == dtype and np.allclose(a, b, rtol=0, atol=atol)


def test_the_fused_pass_matches_a_per_gaussian_brute_force_and_locates_once(monkeypatch):
    """Oracle written here, one Gaussian at a time: its rest tet by brute force over every tet, μ' = Σ b_i d_i,
    F = D'D⁻¹, Σ' = FΣFᵀ, the SH bands rotated by scipy's polar rotation of F; Gaussians outside the proxy and in
    still tets unchanged. Then a second frame and a repeat of the first reuse the location (the locator is not
    called again) and give the same model as a fresh field; other means are located anew."""
    from nerfedit_plugin.bending.locate import locate_brute_force

    vertices, tets = kuhn_grid(4, np.full(3, -0.8), np.full(3, 0.8))
    tets = orient_tets(vertices, tets)
    rng = np.random.default_rng(11)
    frames = [vertices + 0.15 * np.sin(2.0 * vertices[:, [1, 2, 0]]) * (k + 1) for k in range(2)]
    for frame in frames:
        frame[vertices[:, 2] < -0.5] = vertices[vertices[:, 2] < -0.5]  # still tets at the bottom
    field = DeformationField(vertices, tets, np.stack(frames), dtype=torch.float64)
    model = synthetic_model(400, 3, seed=12, radius=1.0, dtype=np.float64)
    model.means[:5] = rng.uniform(0.85, 1.0, size=(5, 3))  # outside the proxy
    located = []
    rest = field._rest()
    original = rest.locate
    monkeypatch.setattr(rest, "locate", lambda x: located.append(len(x)) or original(x))
    for frame in (0, 1, 0):
        out, report = deform_model(model, field, frame)
        tet, bary = locate_brute_force(vertices, tets, torch.from_numpy(model.means), torch.float64)
        still = field.still_tets(frame)
        moving = (tet.numpy() >= 0) & ~still[np.maximum(tet.numpy(), 0)]
        assert report.moved == moving.sum() and 0 < report.moved < len(model)
        for i in range(len(model)):
            if not moving[i]:
                assert all(np.array_equal(a[i], b[i]) for a, b in zip(out.arrays(), model.arrays()))
                continue
            corners = field.deformed_vertices[frame][tets[tet[i]]]
            rest_corners = vertices[tets[tet[i]]]
            f = (corners[1:] - corners[0]).T @ np.linalg.inv((rest_corners[1:] - rest_corners[0]).T)
            assert np.allclose(out.means[i], bary[i].numpy() @ corners, atol=1e-12)
            sigma = covariance(SplatModel(*(a[i : i + 1] for a in model.arrays())))[0]
            assert np.allclose(covariance(SplatModel(*(a[i : i + 1] for a in out.arrays())))[0], f @ sigma @ f.T)
            assert np.allclose(out.sh[i], band_rotation(model.sh[i : i + 1], scipy.linalg.polar(f)[0])[0])
    assert located == [len(model)]  # one location for three calls
    fresh, _ = deform_model(model, DeformationField(vertices, tets, np.stack(frames), dtype=torch.float64), 0)
    assert all(np.array_equal(a, b) for a, b in zip(out.arrays(), fresh.arrays()))
    other = SplatModel(model.means + 0.01, *model.arrays()[1:])
    deform_model(other, field, 0)
    assert located == [len(model), len(model)]
