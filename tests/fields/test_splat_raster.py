"""The splat rasteriser against independent oracles: gsplat 1.5.3's pure-torch reference functions (covariance, EWA
projection, SH colour; they run on the CPU) and a brute-force per-pixel compositor written here."""

import numpy as np
import pytest
import torch

from nerfedit_plugin.data.cameras import Cameras, generate_rays, look_at
from nerfedit_plugin.fields.splats.field import SplatsField
from nerfedit_plugin.fields.splats.model import SplatModel, synthetic_model
from nerfedit_plugin.fields.splats.projection import NEAR, colors, covariances, project, view_matrix
from nerfedit_plugin.fields.splats.rasterize import project_gaussians, rasterize

reference = pytest.importorskip("gsplat.cuda._torch_impl")  # pip install --no-deps gsplat==1.5.3


def _camera(width=40, height=32, eye=(2.2, -1.4, 1.1)) -> Cameras:
    c2w = look_at(torch.tensor([eye], dtype=torch.float32), torch.zeros(1, 3))
    return Cameras(c2w, 38.0, 41.0, width / 2 + 1.3, height / 2 - 0.7, width, height)


def _viewmat(camera: Cameras) -> torch.Tensor:
    rotation, translation = view_matrix(camera.c2w[0].double())
    viewmat = torch.eye(4, dtype=torch.float64)
    viewmat[:3, :3], viewmat[:3, 3] = rotation, translation
    return viewmat


def _tensors(model: SplatModel):
    return [torch.from_numpy(a).double() for a in model.arrays()]


def test_covariance_matches_gsplat():
    means, quats, log_scales, _, _ = _tensors(synthetic_model(300, 0, seed=1))
    expected, _ = reference._quat_scale_to_covar_preci(quats, torch.exp(log_scales))
    torch.testing.assert_close(covariances(quats, log_scales), expected, rtol=1e-12, atol=1e-14)


def test_view_matrix_is_the_opencv_inverse_of_the_opengl_pose():
    camera = _camera()
    c2w = camera.c2w[0].double()
    rotation, translation = view_matrix(c2w)
    torch.testing.assert_close(rotation @ c2w[:3, 3] + translation, torch.zeros(3, dtype=torch.float64))
    forward = -c2w[:3, 2]  # OpenGL looks down -z; OpenCV's camera z is forward
    torch.testing.assert_close(rotation @ forward, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))


@pytest.mark.parametrize("eye", [(2.2, -1.4, 1.1), (0.1, 0.1, 0.3)])  # the second camera stands among the Gaussians
def test_projection_matches_gsplat(eye):
    camera = _camera(eye=eye)
    means, quats, log_scales, _, _ = _tensors(synthetic_model(500, 0, seed=2, scale=(0.02, 0.3)))
    covars = covariances(quats, log_scales)
    K = torch.tensor([[38.0, 0, 20 + 1.3], [0, 41.0, 16 - 0.7], [0, 0, 1]], dtype=torch.float64)
    radii, means2d, depths, conics, comp = reference._fully_fused_projection(
        means, covars, _viewmat(camera)[None], K[None], 40, 32, eps2d=0.3, calc_compensations=True
    )
    ours = project(means, covars, *view_matrix(camera.c2w[0].double()), (38.0, 41.0, 21.3, 15.3), 40, 32)
    front = depths[0] > NEAR
    assert front.sum() > 100 and (front.all() if eye[0] > 1 else (~front).sum() > 50)
    torch.testing.assert_close(ours.depths, depths[0])
    torch.testing.assert_close(ours.means2d[front], means2d[0][front])
    torch.testing.assert_close(ours.conics[front], conics[0][front])
    torch.testing.assert_close(ours.compensation[front], comp[0][front])


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_colours_match_gsplat_spherical_harmonics(degree):
    means, _, _, _, sh = _tensors(synthetic_model(400, degree, seed=degree))
    center = torch.tensor([2.0, -1.0, 0.5], dtype=torch.float64)
    expected = torch.clamp(reference._spherical_harmonics(degree, means - center, sh) + 0.5, min=0.0)
    torch.testing.assert_close(colors(sh, means, center), expected, rtol=1e-12, atol=1e-12)


def brute_force(means2d, conics, rgb, opacity, depths, width, height, background):
    """Every pixel, every Gaussian, in depth order (stable): the compositing rule, written out in float32."""
    order = np.argsort(depths, kind="stable")
    order = order[depths[order] > NEAR]
    image = np.zeros((height, width, 3), dtype=np.float32)
    for y in range(height):
        for x in range(width):
            T, C = np.float32(1.0), np.zeros(3, dtype=np.float32)
            for g in order:
                d = np.array([x + 0.5, y + 0.5], dtype=np.float32) - means2d[g]
                a, b, c = conics[g]
                power = np.float32(-0.5) * (a * d[0] * d[0] + c * d[1] * d[1]) - b * d[0] * d[1]
                if power > 0:
                    continue
                alpha = min(np.float32(0.99), opacity[g] * np.exp(power))
                if alpha < np.float32(1 / 255):
                    continue
                if T * (1 - alpha) < np.float32(1e-4):
                    break
                C += alpha * T * rgb[g]
                T = T * (np.float32(1.0) - alpha)
            image[y, x] = C + T * np.asarray(background, dtype=np.float32)
    return image


@pytest.mark.parametrize("seed, opaque", [(0, False), (1, True)])
def test_compositor_matches_brute_force(seed, opaque):
    """A 40×32 image (tiles cut at the border), Gaussians of every size, some behind the camera, some so opaque that
    pixels stop early."""
    camera = _camera(eye=(1.6, -1.0, 0.8))
    model = synthetic_model(250, 2, seed=seed, scale=(0.005, 0.25))
    if opaque:
        model.opacities[:] = 6.0
    means, quats, log_scales, logits, sh = (torch.from_numpy(a) for a in model.arrays())
    p = project(means, covariances(quats, log_scales), *view_matrix(camera.c2w[0]), (38.0, 41.0, 21.3, 15.3), 40, 32)
    rgb = colors(sh, means, camera.c2w[0, :3, 3])
    opacity = torch.sigmoid(logits)
    background = (0.2, 0.5, 0.9)
    image, transmittance = rasterize(
        p.means2d, p.conics, p.covars2d.diagonal(0, 1, 2), rgb, opacity, p.depths, 40, 32, background
    )
    expected = brute_force(*(t.numpy() for t in (p.means2d, p.conics, rgb, opacity, p.depths)), 40, 32, background)
    np.testing.assert_allclose(image.numpy(), expected, atol=2e-5)
    assert (transmittance < 0.5).any() and (transmittance > 0.99).any()


def test_a_gaussian_appears_where_the_camera_ray_through_its_pixel_goes():
    """The OpenGL → OpenCV flip and the pixel-centre convention: a small Gaussian on the ray of pixel (29, 7) lights
    exactly that pixel."""
    camera = _camera()
    origins, directions = generate_rays(camera, 0)
    point = origins[7, 29] + 2.5 * directions[7, 29]
    model = SplatModel(
        point[None].numpy(),
        np.array([[1.0, 0, 0, 0]], dtype=np.float32),
        np.full((1, 3), np.log(0.002), dtype=np.float32),
        np.array([8.0], dtype=np.float32),
        np.zeros((1, 1, 3), dtype=np.float32),
    )
    field = SplatsField.from_model(model)
    image = field.render(camera, 0, None)
    darkest = np.unravel_index(np.argmin(image.sum(-1).numpy()), image.shape[:2])
    assert darkest == (7, 29)
    assert field.last_stats.visible == 1 and set(field.last_stats.seconds) == {
        "project",
        "cull",
        "sort",
        "tiles",
        "composite",
    }


@pytest.mark.parametrize("antialiased", [False, True])
def test_compiled_projection_matches_the_torch_path(antialiased):
    camera = _camera(eye=(0.4, -0.3, 0.5))  # some Gaussians behind the camera, some far outside the frustum
    model = synthetic_model(300, 3, seed=9, scale=(0.005, 0.2))
    means, quats, log_scales, logits, sh = _tensors(model)
    c2w = camera.c2w[0].double()
    intrinsics = (38.0, 41.0, 21.3, 15.3)
    p = project(means, covariances(quats, log_scales), *view_matrix(c2w), intrinsics, 40, 32)
    opacity = torch.sigmoid(logits) * (p.compensation if antialiased else 1.0)
    expected = [p.means2d, p.conics, p.covars2d.diagonal(0, 1, 2), colors(sh, means, c2w[:3, 3]), opacity, p.depths]
    got = project_gaussians(*model.arrays(), c2w.numpy(), intrinsics, 40, 32, antialiased)
    front = p.depths > NEAR
    for name, a, b in zip(("means2d", "conics", "variances", "colors", "opacities", "depths"), got, expected):
        torch.testing.assert_close(a[front].double(), b[front], rtol=2e-6, atol=1e-5, msg=name)
