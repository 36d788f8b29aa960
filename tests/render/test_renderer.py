"""The shared renderer: closed-form quadrature, NeuS opacity, autograd, supersampling, and ray bending — identity
bending changes nothing, rigid bending equals moving the camera inversely (density, sdf and opaque mesh fields),
vacated space shows the background, moved parts outside the scene box are still rendered."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.data.cameras import Cameras, generate_rays, look_at
from nerfedit_plugin.data.synthetic import colorize, render_mesh
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.fields.mesh_field import MeshField
from nerfedit_plugin.render.renderer import (
    RenderConfig,
    ray_box,
    render_image,
    render_rays,
    sampling_box,
)

COLOR_POS = torch.tensor([[1.5, -0.7, 0.3], [0.4, 1.1, -1.2], [-0.9, 0.2, 1.4]])
COLOR_DIR = torch.tensor([[0.8, 0.1, -0.5], [-0.3, 0.9, 0.2], [0.2, -0.6, 0.7]])


def view_dependent_color(points: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    return torch.sigmoid(points @ COLOR_POS + directions @ COLOR_DIR)


class AnalyticField(Field):
    """Fields given by a formula: nothing to extract for these tests."""

    def extract_mesh(self, resolution=256, level=None):
        raise NotImplementedError


class ConstantField(AnalyticField):
    """Density σ and colour c everywhere."""

    def __init__(self, scene_bbox, sigma: float, color) -> None:
        super().__init__(FieldConfig(), scene_bbox)
        self.sigma, self.color = sigma, torch.tensor(color)

    def query(self, points, directions):
        return torch.full((len(points),), self.sigma), self.color.expand(len(points), 3)


class BallField(AnalyticField):
    """Density σ₀ (1 − |x|²/r²)²₊ in a ball, view-dependent colour; like the nerf backend's occupancy grid, its
    ``occupied`` rejects points outside the scene box."""

    def __init__(self, scene_bbox, radius: float = 0.3) -> None:
        super().__init__(FieldConfig(), scene_bbox)
        self.radius = radius
        self.sigma = torch.nn.Parameter(torch.tensor(60.0))

    def query(self, points, directions):
        q = (points**2).sum(-1) / self.radius**2
        return self.sigma * (1 - q).clamp_min(0) ** 2, view_dependent_color(points, directions)

    def occupied(self, points):
        return ((points >= self.scene_bbox[0]) & (points <= self.scene_bbox[1])).all(-1)


class SphereSDF(AnalyticField):
    """Signed distance to a sphere, view-dependent colour, NeuS sharpness ``s``."""

    kind = "sdf"

    def __init__(self, scene_bbox, radius: float = 0.3, s: float = 400.0) -> None:
        super().__init__(FieldConfig(), scene_bbox)
        self.radius = torch.nn.Parameter(torch.tensor(radius))
        self.s = torch.nn.Parameter(torch.tensor(s))

    def query(self, points, directions):
        return points.norm(dim=-1) - self.radius, view_dependent_color(points, directions)

    def sharpness(self):
        return self.s


def rigid(axis, degrees: float, translation) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation matrix (Rodrigues) and translation of the map x ↦ R x + t."""
    axis = torch.tensor(axis, dtype=torch.float64)
    axis = axis / axis.norm()
    k = torch.tensor([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = math.radians(degrees)
    rotation = torch.eye(3, dtype=torch.float64) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
    return rotation, torch.tensor(translation, dtype=torch.float64)


ROTATION, TRANSLATION = rigid((1.0, 2.0, 0.5), 35.0, (0.45, -0.1, 0.5))
SHIFT = np.array([1.6, 0.0, 0.0])
IDENTITY_FRAME, RIGID_FRAME, SHIFT_FRAME = 0, 1, 2


@pytest.fixture(scope="module")
def deformation(capsule_proxy) -> DeformationField:
    """One field, three frames of the capsule's proxy: unchanged, moved rigidly by (ROTATION, TRANSLATION), and
    translated by SHIFT clear of its rest place (frames share the point locator of the rest proxy)."""
    rest = capsule_proxy.vertices
    frames = [rest, rest @ ROTATION.numpy().T + TRANSLATION.numpy(), rest + SHIFT]
    return DeformationField(rest, capsule_proxy.tets, np.stack(frames))


@pytest.fixture(scope="module")
def box(capsule_proxy) -> torch.Tensor:
    """A scene box enclosing the capsule's proxy (so identity bending leaves the sampling box unchanged)."""
    vertices = torch.from_numpy(capsule_proxy.vertices)
    return torch.stack([vertices.amin(0) - 0.1, vertices.amax(0) + 0.1]).float()


@pytest.fixture(scope="module")
def fields(capsule, box) -> dict[str, Field]:
    mesh_field = MeshField.from_mesh(colorize(capsule, seed=2))
    mesh_field.scene_bbox.copy_(box)
    return {"density": BallField(box), "sdf": SphereSDF(box), "mesh": mesh_field}


def cameras(n: int, target=(0.0, 0.0, 0.0), distance: float = 3.5, size: int = 40, fov: float = 0.75) -> Cameras:
    eyes = torch.tensor([[1.0, -2.0, 0.6], [-1.5, -1.0, -1.2], [0.3, 2.0, 1.5]])[:n]
    eyes = torch.tensor(target) + distance * eyes / eyes.norm(dim=1, keepdim=True)
    return Cameras.from_fov(look_at(eyes, torch.tensor(target).expand(n, 3)), size, size, fov)


def flat_rays(cams: Cameras, index: int) -> tuple[torch.Tensor, torch.Tensor]:
    origins, directions = generate_rays(cams, index)
    return origins.reshape(-1, 3), directions.reshape(-1, 3)


def test_ray_box_clips_rays_to_the_box():
    box = torch.tensor([[-1.0, -2.0, -3.0], [1.0, 2.0, 3.0]])
    origins = torch.tensor([[-5.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-5.0, 5.0, 0.0], [0.0, 0.0, 5.0]])
    directions = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, -0.8]])
    near, far = ray_box(origins, directions, box)
    # enters/leaves through x = ∓1; starts inside (near clamped to 0); misses (empty interval); enters z = 3 at
    # t = 2.5 and leaves through y = 2 at t = 3.33.
    assert torch.allclose(near, torch.tensor([4.0, 0.0, near[2].item(), 2.5]))
    assert torch.allclose(far, torch.tensor([6.0, 2.0, near[2].item(), 2 / 0.6]))


def test_density_quadrature_matches_the_closed_form():
    """Constant σ over the whole box: w_i = q^i (1 − q), q = e^{−σδ}, so opacity = 1 − e^{−σL} and the depth is a
    geometric series — exactly, also with stratified samples (bins keep their width δ)."""
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = ConstantField(box, sigma=1.7, color=(0.2, 0.5, 0.9))
    yz = torch.rand(50, 2) * 1.8 - 0.9
    origins = torch.cat([torch.full((50, 1), -3.0), yz], dim=1)
    directions = torch.tensor([[1.0, 0.0, 0.0]]).expand(50, 3)
    config = RenderConfig(n_samples=64, background=(1.0, 0.0, 0.5))
    n, sigma, near, length = 64, 1.7, 2.0, 2.0
    q = math.exp(-sigma * length / n)
    opacity = 1 - math.exp(-sigma * length)
    mean_index = (q - n * q**n + (n - 1) * q ** (n + 1)) / (1 - q) ** 2 * (1 - q) / opacity  # Σ i w_i / Σ w_i
    depth = near + (mean_index + 0.5) * length / n
    out = render_rays(field, origins, directions, config)
    assert torch.allclose(out.opacity, torch.tensor(opacity), atol=1e-6)
    assert torch.allclose(out.depth, torch.tensor(depth), atol=1e-5)
    expected = opacity * torch.tensor([0.2, 0.5, 0.9]) + (1 - opacity) * torch.tensor([1.0, 0.0, 0.5])
    assert torch.allclose(out.rgb, expected.expand(50, 3), atol=1e-6)
    stratified = render_rays(field, origins, directions, config, stratified=True)
    assert torch.allclose(stratified.opacity, out.opacity, atol=1e-6)
    assert not torch.allclose(stratified.depth, out.depth, atol=1e-6)
    assert ((stratified.depth > near) & (stratified.depth < near + length)).all()


def test_sdf_rendering_finds_the_sphere():
    """NeuS opacity: rays through the sphere are opaque with depth at the analytic intersection (unbiased to well
    within a sample spacing), rays that miss it stay transparent."""
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = SphereSDF(box, radius=0.5, s=400.0)
    origins, directions = flat_rays(cameras(1, distance=3.0, size=32, fov=0.6), 0)
    out = render_rays(field, origins, directions, RenderConfig(n_samples=256))
    along = -(origins * directions).sum(1)
    gap = origins.norm(dim=1) ** 2 - along**2  # squared distance of the ray from the centre
    hit, miss = gap < 0.45**2, gap > 0.55**2
    assert hit.sum() > 100 and miss.sum() > 100
    truth = along - torch.sqrt((0.25 - gap).clamp_min(0))
    spacing = 2 * math.sqrt(3) / 256
    assert (out.opacity[hit] > 0.999).all()
    assert (out.depth[hit] - truth[hit]).abs().max() < 0.25 * spacing
    assert (out.opacity[miss] < 0.01).all()


def test_render_rays_is_differentiable():
    """Training goes through render_rays: gradients reach every parameter, and match finite differences (for the
    sdf field they flow through NeuS's cosine term, which uses ∇f computed with create_graph)."""
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    origins, directions = flat_rays(cameras(1, distance=3.0, size=12, fov=0.5), 0)
    config = RenderConfig(n_samples=96)
    cases = ((BallField(box, radius=0.6), ("sigma",)), (SphereSDF(box, radius=0.5, s=30.0), ("radius", "s")))
    for field, params in cases:
        loss = render_rays(field, origins, directions, config).rgb.square().sum()
        grads = torch.autograd.grad(loss, [getattr(field, p) for p in params])
        for name, grad in zip(params, grads):
            param, step = getattr(field, name), 1e-2 * getattr(field, name).item()
            with torch.no_grad():
                param += step
                up = render_rays(field, origins, directions, config).rgb.square().sum()
                param -= 2 * step
                down = render_rays(field, origins, directions, config).rgb.square().sum()
                param += step
            numeric = (up - down) / (2 * step)
            assert grad.abs() > 1e-3 and torch.isclose(grad, numeric, rtol=2e-2), (type(field).__name__, name)


def test_render_image_supersamples_and_chunks(fields):
    cams = cameras(1, size=10)
    field = fields["density"]
    image = render_image(field, cams, 0, RenderConfig(chunk=37), supersample=3)
    fine = render_image(field, cams.upscale(3), 0, RenderConfig(chunk=100000))
    assert image.shape == (10, 10, 3)
    assert torch.allclose(image, fine.view(10, 3, 10, 3, 3).mean((1, 3)), atol=1e-6)


def test_early_stop_drops_at_most_the_threshold(fields):
    """render_image marches rays front to back and stops them once their transmittance is ≤ early_stop: the
    image differs from compositing every sample by at most that much."""
    cams = cameras(1, size=24)
    for kind in ("density", "sdf"):
        full = render_image(fields[kind], cams, 0, RenderConfig(n_samples=96, early_stop=0.0))
        stopped = render_image(fields[kind], cams, 0, RenderConfig(n_samples=96, early_stop=1e-3))
        assert full.std() > 0.05
        assert (stopped - full).abs().max() <= 1e-3


@pytest.mark.parametrize("kind", ["density", "sdf", "mesh"])
def test_identity_deformation_renders_the_unedited_image(kind, fields, deformation):
    field, config, cams = fields[kind], RenderConfig(n_samples=96), cameras(2, size=24)
    for i in range(2):
        plain = render_image(field, cams, i, config)
        edited = render_image(field, cams, i, config, deformation=deformation, frame=IDENTITY_FRAME)
        assert plain.std() > 0.05  # the object is in view
        # still tets give every sample back unchanged; view directions pass through normalize(J d): one rounding
        torch.testing.assert_close(edited, plain, atol=1e-6, rtol=0)


def test_identity_deformation_of_a_proxy_larger_than_the_scene_box_keeps_the_samples(capsule, deformation):
    """A proxy reaches beyond a tight scene box (the usual case: the cage is offset from the surface); unmoved tets
    add nothing to the sampling box, so every ray is sampled as without the deformation (a grown box would shift
    every sample and change silhouettes)."""
    lo, hi = capsule.vertices.min(0), capsule.vertices.max(0)
    tight = torch.tensor(np.stack([lo - 0.01, hi + 0.01])).float()
    proxy = deformation.rest_vertices
    assert (proxy.min(0) < tight[0].numpy()).all() and (proxy.max(0) > tight[1].numpy()).all()
    field, config, cams = BallField(tight), RenderConfig(n_samples=48), cameras(1, size=24)
    torch.testing.assert_close(sampling_box(field, deformation, IDENTITY_FRAME), tight, atol=0, rtol=0)
    plain = render_image(field, cams, 0, config)
    edited = render_image(field, cams, 0, config, deformation=deformation, frame=IDENTITY_FRAME)
    assert plain.std() > 0.05
    torch.testing.assert_close(edited, plain, atol=1e-6, rtol=0)


@pytest.mark.parametrize("kind, tolerance", [("density", 1e-4), ("sdf", 5e-3), ("mesh", 1e-4)])
def test_rigid_deformation_equals_moving_the_camera_inversely(kind, tolerance, fields, box, deformation):
    """Proxy moved by G: x ↦ R x + t. Rays of a camera c2w through the bent field = rays of the camera G⁻¹·c2w
    through the unedited field, sample for sample (same per-ray bounds). The motion takes part of the object out of
    the scene box, where the ball field's occupancy grid would skip it if it were evaluated before bending.
    (The sdf tolerance covers NeuS's +1e-5 in every α: vacated samples are exactly empty, their unedited twins far
    outside the sphere are not.)"""
    assert TRANSLATION[0] + 0.3 > box[1, 0]  # the moved ball leaves the scene box
    inverse = torch.eye(4, dtype=torch.float64)
    inverse[:3, :3], inverse[:3, 3] = ROTATION.T, -ROTATION.T @ TRANSLATION
    cams = cameras(2, target=(0.2, 0.0, 0.25), size=32)
    moved_cams = Cameras((inverse.float() @ cams.c2w), cams.fx, cams.fy, cams.cx, cams.cy, cams.width, cams.height)
    field, config = fields[kind], RenderConfig(n_samples=192)
    for i in range(2):
        origins, directions = flat_rays(cams, i)
        bounds = ray_box(origins, directions, sampling_box(field, deformation, RIGID_FRAME))
        edited = render_rays(
            field, origins, directions, config, deformation=deformation, frame=RIGID_FRAME, bounds=bounds
        )
        expected = render_rays(field, *flat_rays(moved_cams, i), config, bounds=bounds)
        plain = render_rays(field, origins, directions, config, bounds=bounds)
        assert (edited.rgb - plain.rgb).abs().max() > 0.3  # the edit is visible
        assert (edited.opacity - expected.opacity).abs().max() < tolerance
        same = torch.ones_like(edited.opacity, dtype=torch.bool)
        if field.opaque:  # the surface crossing is refined by bisection; the depths agree up to rounding, except
            # where a probe lies within rounding of the surface: then the two renders may refine a different crossing
            # of a ray that grazes the surface, always within the coarse step that holds the first inside sample
            step = (bounds[1] - bounds[0]) / (config.n_samples - 1)
            gap = (edited.depth - expected.depth).abs()
            assert (gap <= 2 * step).all()
            same = gap < 1e-5
            assert same.float().mean() > 0.99
        assert (edited.rgb - expected.rgb)[same].abs().max() < tolerance


def test_vacated_space_renders_the_background(fields, capsule, deformation):
    """The whole proxy translated clear of its rest place: where the object was, the background shows; the moved
    object renders exactly like the translated mesh (translation keeps the mesh field exact)."""
    field, background = fields["mesh"], (0.1, 0.2, 0.3)
    cams = cameras(2, target=(0.8, 0.0, 0.0), distance=5.0, size=48, fov=0.8)
    mesh = colorize(capsule, seed=2)
    truth, alpha_moved, _ = render_mesh(mesh.with_vertices(mesh.vertices + SHIFT), cams, background=background)
    _, alpha_rest, _ = render_mesh(mesh, cams)
    for i in range(2):
        image = render_image(
            field, cams, i, RenderConfig(background=background), deformation=deformation, frame=SHIFT_FRAME
        ).numpy()
        vacated = (alpha_rest[i] > 0) & (alpha_moved[i] == 0)
        assert vacated.sum() > 50
        assert np.array_equal(image[vacated], np.broadcast_to(np.float32(background), (vacated.sum(), 3)))
        assert np.mean(np.abs(image - truth[i]).max(-1) > 1e-3) < 0.01


SHEAR = np.array([[1.35, 0.25, 0.0], [-0.1, 0.7, 0.2], [0.15, 0.0, 1.2]])
SHEAR_SHIFT = np.array([0.3, -0.25, 0.35])


class HandBentField(AnalyticField):
    """``field`` seen through the affine map G: x ↦ A x + b, bent by hand: density (or sdf) at ``A⁻¹(x − b)`` and
    colour for the view direction ``A⁻¹ d / |A⁻¹ d|`` (normalised here, independently of the renderer)."""

    def __init__(self, field: Field, matrix: np.ndarray, shift: np.ndarray) -> None:
        super().__init__(FieldConfig(), field.scene_bbox)
        self.field, self.kind = field, field.kind
        self.inverse = torch.linalg.inv(torch.from_numpy(matrix)).float()
        self.shift = torch.from_numpy(shift).float()

    def query(self, points, directions):
        canonical = (points - self.shift) @ self.inverse.T
        bent = directions @ self.inverse.T
        return self.field.query(canonical, bent / bent.norm(dim=-1, keepdim=True))

    def sharpness(self):
        return self.field.sharpness()


@pytest.fixture(scope="module")
def sheared(capsule_proxy) -> DeformationField:
    """The capsule's proxy moved by G: x ↦ SHEAR x + SHEAR_SHIFT."""
    rest = capsule_proxy.vertices
    return DeformationField(rest, capsule_proxy.tets, rest @ SHEAR.T + SHEAR_SHIFT)


@pytest.mark.parametrize("kind, tolerance", [("density", 1e-5), ("sdf", 5e-3)])
def test_non_rigid_bending_queries_normalised_bent_view_directions(kind, tolerance, fields, sheared):
    """Proxy moved by a shearing, non-uniformly scaling affine map G: x ↦ A x + b (every tet has J = A⁻¹, which
    changes the length of view directions by factors 0.7–1.5). The bent render of a view-dependent field equals the
    unedited render of the field composed with G⁻¹ by hand, whose colour is queried with normalize(A⁻¹ d): same rays,
    same per-ray bounds. Outside G(proxy) both are empty (the ball lies inside the proxy)."""
    deformation = sheared
    assert not deformation.still_tets(0).any()  # the affine map has no fixed point in the proxy
    field, config = fields[kind], RenderConfig(n_samples=128, early_stop=0.0)
    lengths = np.linalg.norm(np.linalg.inv(SHEAR) @ np.random.default_rng(1).normal(size=(3, 200)), axis=0)
    assert lengths.min() < 0.9 and lengths.max() > 1.1  # J d is far from unit length for most directions
    cams = cameras(2, target=(0.3, -0.25, 0.35), size=16, fov=0.3)
    for i in range(2):
        origins, directions = flat_rays(cams, i)
        bounds = ray_box(origins, directions, sampling_box(field, deformation, 0))
        with torch.no_grad():
            edited = render_rays(field, origins, directions, config, deformation=deformation, bounds=bounds)
            hand_bent = HandBentField(field, SHEAR, SHEAR_SHIFT)
            expected = render_rays(hand_bent, origins, directions, config, bounds=bounds)
            plain = render_rays(field, origins, directions, config, bounds=bounds)
        assert (edited.rgb - plain.rgb).abs().max() > 0.3  # the edit is visible
        assert (edited.opacity > 0.5).sum() > 30  # the object is in view
        assert (edited.opacity - expected.opacity).abs().max() < tolerance
        assert (edited.rgb - expected.rgb).abs().max() < tolerance


def scenery(box: torch.Tensor, fg_scale: float, fg_shift: float) -> Field:
    """A nerf field over ``box`` with random foreground content (density logits ``fg_scale · N(0,1) + fg_shift``)
    and a background model of random content."""
    from nerfedit_plugin.fields.nerf import NerfConfig

    config = NerfConfig(resolution=16, upsample_steps=(), occupancy_resolution=0, background="field")
    field = dataclasses.replace(config, background_resolution=16).setup(scene_bbox=box)
    g = torch.Generator().manual_seed(4)
    with torch.no_grad():
        field.grid.table.normal_(0.0, 1.0, generator=g)
        field.grid.table[:, 0] = field.grid.table[:, 0] * fg_scale + fg_shift
        field.background.grid.table.normal_(0.0, 3.0, generator=g)
    return field


def test_deformations_never_touch_the_background_model(box, deformation):
    """Background samples are composited at their unbent positions: an identity deformation renders the unedited
    image, and moving the whole proxy clear of its rest place (over background content) changes nothing when the
    foreground is empty."""
    config, cams = RenderConfig(n_samples=64), cameras(2, target=(0.8, 0.0, 0.0), distance=5.0, size=24, fov=0.8)
    field = scenery(box, 3.0, 0.0)
    empty = scenery(box, 0.0, -40.0)
    for i in range(2):
        plain = render_image(field, cams, i, config)
        edited = render_image(field, cams, i, config, deformation=deformation, frame=IDENTITY_FRAME)
        assert plain.std() > 0.05
        torch.testing.assert_close(edited, plain, atol=1e-6, rtol=0)
        plain = render_image(empty, cams, i, config)
        moved = render_image(empty, cams, i, config, deformation=deformation, frame=SHIFT_FRAME)
        assert plain.std() > 0.05
        torch.testing.assert_close(moved, plain, atol=1e-5, rtol=0)
