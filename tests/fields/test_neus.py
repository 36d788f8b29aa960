"""The neus backend: the initial field is a sphere's signed distance, the eikonal loss vanishes exactly on distance
fields the grid represents exactly, the occupancy band is conservative, the zero level set of the initial field is
the sphere, training improves PSNR, and checkpoints round trip (and refuse other backends)."""

import dataclasses

import numpy as np
import pytest
import torch

from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.checkpoint import load_field
from nerfedit_plugin.fields.nerf import NerfConfig, NerfField
from nerfedit_plugin.fields.neus import NeusConfig, NeusField
from nerfedit_plugin.fields.occupancy import silhouette_depths
from nerfedit_plugin.render.renderer import RenderConfig
from nerfedit_plugin.training.trainer import evaluate

BOX = torch.tensor([[-0.5, -0.4, -0.3], [0.5, 0.4, 0.3]])
RADIUS = 0.5 * 0.3  # init_radius × the smallest half side of BOX


def random_points(n, box=BOX, seed=0):
    g = torch.Generator().manual_seed(seed)
    return box[0] + torch.rand(n, 3, generator=g) * (box[1] - box[0])


def sdf(field, points):
    return field.query(points, torch.zeros_like(points))[0]


def test_grid_gradient_is_the_derivative_of_the_interpolant():
    """DenseGrid.value_and_gradient matches forward() and autograd's derivative of it; NeusField.query hands that
    gradient to autograd (what the renderer's NeuS cosine differentiates) and the gradient stays differentiable
    with respect to the grid."""
    from nerfedit_plugin.fields.encoding import DenseGrid

    grid = DenseGrid(BOX, 6, 3, init=torch.randn(7**3, 3, generator=torch.Generator().manual_seed(5)))
    points = random_points(300, seed=6).requires_grad_(True)
    values, gradient = grid.value_and_gradient(points)
    torch.testing.assert_close(values, grid(points))
    for c in range(3):
        (expected,) = torch.autograd.grad(grid(points)[:, c].sum(), points)
        torch.testing.assert_close(gradient[:, :, c], expected, atol=1e-4, rtol=1e-4)
    field = NeusConfig(resolution=8, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    with torch.no_grad():
        field.grid.table.normal_(generator=torch.Generator().manual_seed(7))
    sdf, _ = field.query(points, torch.zeros_like(points))
    (through_query,) = torch.autograd.grad(sdf.sum(), points, create_graph=True)
    (plain,) = torch.autograd.grad(field.grid(points)[:, 0].sum() * field.cell, points)
    torch.testing.assert_close(through_query, plain, atol=1e-4, rtol=1e-4)
    assert torch.autograd.grad(through_query.square().sum(), field.grid.table)[0].abs().sum() > 0


def test_initial_field_is_the_signed_distance_of_a_sphere():
    field = NeusConfig(resolution=32, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    vertices = field.grid.vertex_points().reshape(-1, 3)
    torch.testing.assert_close(sdf(field, vertices), vertices.norm(dim=1) - RADIUS, atol=1e-6, rtol=0)
    # between vertices, trilinear interpolation errs by at most Σₐ hₐ²/8 · max|∂ₐ²f| ≤ 3h²/(8ρ) with ρ the least
    # distance from the centre over the point's cell (|∂ₐ²|x|| ≤ 1/|x|)
    points = random_points(20_000)
    h = float((BOX[1] - BOX[0]).max()) / 32
    rho = points.norm(dim=1) - 3**0.5 * h
    points, rho = points[rho > RADIUS / 2], rho[rho > RADIUS / 2]
    error = (sdf(field, points) - (points.norm(dim=1) - RADIUS)).abs()
    assert error.max() > 1e-4 and (error <= 3 * h * h / (8 * rho) + 1e-6).all()
    assert field.kind == "sdf" and float(field.sharpness().detach() * field.cell) == pytest.approx(
        field.config.sharpness_init
    )


def test_eikonal_loss_vanishes_on_exact_distance_fields():
    """Zero for a plane's distance (affine: represented exactly), one for twice that distance, near zero for the
    sphere's interpolated distance."""
    field = NeusConfig(resolution=16, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    points = random_points(5000, seed=1)
    normal = torch.nn.functional.normalize(torch.tensor([1.0, -2.0, 0.5]), dim=0)
    vertices = field.grid.vertex_points().reshape(-1, 3)
    with torch.no_grad():  # a plane's signed distance is affine: the grid represents it exactly
        field.grid.table[:, 0] = (vertices @ normal - 0.1) / field.cell
    assert float(field.eikonal_loss(points).detach()) == pytest.approx(0.0, abs=1e-10)
    with torch.no_grad():  # twice the distance: |∇f| = 2 everywhere
        field.grid.table[:, 0] *= 2
    assert float(field.eikonal_loss(points).detach()) == pytest.approx(1.0, abs=1e-5)
    # the initial sphere: |∇f| = 1 up to the interpolation error, away from the centre's cell
    sphere = NeusConfig(resolution=32, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    far = points[points.norm(dim=1) > 0.15]
    assert sphere.eikonal_loss(far) < 1e-3
    assert sphere.eikonal_loss(far) < field.eikonal_loss(far)


def test_occupancy_band_is_exact_and_conservative():
    field = NeusConfig(
        resolution=32, upsample_steps=(), occupancy_resolution=8, occupancy_dilation=0, sharpness_init=1.0
    ).setup(scene_bbox=BOX)
    with torch.no_grad():
        field.grid.table[:, 0] += torch.randn(33**3, generator=torch.Generator().manual_seed(2))
    field.update_occupancy()
    band = field.config.occupancy_band / float(field.sharpness().detach())
    assert 0.05 < field.occupancy.fraction < 0.95
    points = random_points(200_000, seed=3)
    near = sdf(field, points).abs() <= band
    assert near.any() and field.occupied(points)[near].all()
    # exact: every occupied cell holds a grid vertex within the band or a sign change
    assert field.cell_min_distance().le(band).eq(field.occupancy.mask).all()


def test_extract_mesh_of_the_initial_sphere():
    field = NeusConfig(resolution=32, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    mesh = field.extract_mesh(resolution=64)
    r = np.linalg.norm(mesh.vertices, axis=1)
    h = float((BOX[1] - BOX[0]).max()) / 32
    assert np.abs(r - RADIUS).max() < h * h / RADIUS  # the zero set of the interpolated distance
    area = mesh.to_trimesh().area
    assert area == pytest.approx(4 * np.pi * RADIUS**2, rel=0.02)
    v = mesh.vertices[mesh.faces]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert (np.einsum("ij,ij->i", normals, v.mean(1)) > 0).all()  # faces wind outward
    assert mesh.vertex_colors.shape == (len(mesh.vertices), 3)
    with pytest.raises(ValueError, match="outside the range"):
        field.extract_mesh(resolution=16, level=5.0)


def test_visual_hull_initialisation_of_a_ball(tmp_path):
    """The signed distance to the visual hull of a rendered ball: negative at every vertex inside the ball (the hull
    contains the object), positive a little outside it (only what every camera sees can be inside) and close to the
    ball's own distance near its surface."""
    import trimesh

    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    ball = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    SurfaceMesh(ball.vertices, ball.faces).save(tmp_path / "ball.ply")
    data = load_dataset(
        generate_dataset(
            GenerateConfig(
                out=tmp_path / "data", mesh=str(tmp_path / "ball.ply"), resolution=48, n_train=12, n_val=1, n_test=1
            )
        )
    )
    config = NeusConfig(resolution=32, upsample_steps=(), occupancy_resolution=0, init_shell=0)
    field = config.setup(scene_bbox=data.scene_bbox)
    field.init_from_hull(data.cameras, silhouette_depths(data.alpha > 0))
    vertices = field.grid.vertex_points().reshape(-1, 3)
    radius, truth = 0.5, vertices.norm(dim=1) - 0.5  # the generator scales the ball to a diameter of 1
    values = sdf(field, vertices)
    assert (values[truth < -0.03] < 0).all() and (values[truth > 0.05] > 0).all()
    near = truth.abs() < 0.1
    assert (values[near] - truth[near]).abs().mean() < 0.02 * radius * 2
    # the default start is the hull's shell: |d + t/2| − t/2 of the solid hull's distance d, hollow inside
    shell = dataclasses.replace(config, init_shell=3.0).setup(scene_bbox=data.scene_bbox)
    shell.init_from_hull(data.cameras, silhouette_depths(data.alpha > 0))
    t = 3.0 * shell.cell
    torch.testing.assert_close(sdf(shell, vertices), (values + t / 2).abs() - t / 2, atol=1e-5, rtol=0)
    assert (sdf(shell, vertices)[truth < -0.03 - t] > 0).all()


def test_enclosed_voids_are_filled_and_open_cavities_kept():
    """``fill_voids`` flips the sign inside a closed hollow shell (one surface is extracted, the outer one) and inside
    a shell pierced by pinholes one grid vertex wide (``fill_gap=1``; kept with ``fill_gap=0``), and keeps a cavity
    that opens to the border through a wide hole as it is."""
    config = NeusConfig(resolution=32, upsample_steps=(), occupancy_resolution=0)
    field = config.setup(scene_bbox=BOX)
    vertices = field.grid.vertex_points().reshape(-1, 3)
    r, outer, wall = vertices.norm(dim=1), 0.25, 0.06
    hollow = (r - (outer - wall / 2)).abs() - wall / 2
    axis = vertices[:, :2].norm(dim=1)  # holes along z through both sides: the vertex column on the axis, or wide
    pinholed = torch.maximum(hollow, -(axis - 0.6 * float((BOX[1] - BOX[0]).min()) / 32))
    pierced = torch.maximum(hollow, -(axis - 0.08))
    for values, gap, filled in ((hollow, 1, True), (pinholed, 1, True), (pinholed, 0, False), (pierced, 1, False)):
        field = dataclasses.replace(config, fill_gap=gap).setup(scene_bbox=BOX)
        field.grid.table.data[:, 0] = values / field.cell
        before = field.grid.table[:, 0].clone()
        field.fill_voids()
        after = sdf(field, vertices).detach()
        if filled:
            assert (after[r < outer - wall] < 0).all()
            torch.testing.assert_close(after.abs(), values.abs())  # only signs change
            assert not ((after > 0) & (values < 0)).any()  # flipped: outside vertices only
            area = field.extract_mesh(resolution=64).to_trimesh().area
            assert area == pytest.approx(4 * np.pi * outer**2, rel=0.03)  # the outer sphere alone
        else:
            assert torch.equal(field.grid.table[:, 0], before)  # bit for bit


def test_opaque_images_start_from_the_box_surface(monkeypatch):
    """Opaque images (no silhouettes) have the whole box as visual hull: ``fit`` starts from the signed distance to
    the box shrunk by two cells — exact at the vertices (−(smallest half side − 2h) at the centre, positive at the
    corners) — instead of the sphere."""
    field = NeusConfig(resolution=16, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    field.init_from_box()
    vertices = field.grid.vertex_points().reshape(-1, 3)
    q = vertices.abs() - ((BOX[1] - BOX[0]) / 2 - 2 * field.cell)
    truth = q.clamp_min(0).norm(dim=1) + q.amax(1).clamp_max(0)
    torch.testing.assert_close(sdf(field, vertices), truth, atol=1e-6, rtol=0)
    centre = sdf(field, torch.zeros(1, 3)).detach()
    assert float(centre) == pytest.approx(-(0.3 - 2 * field.cell), abs=1e-6) and (sdf(field, BOX) > 0).all()

    class Opaque:  # what fit reads before training: no alpha, so no silhouettes
        opaque, alpha, border_coverage = True, None, 1.0

    started = []
    monkeypatch.setattr("nerfedit_plugin.fields.neus.train", lambda field, *a, **k: started.append(field) or {})
    config = NeusConfig(resolution=16, upsample_steps=(), occupancy_resolution=0, ground_layer=0, far_layer=0)
    fresh = config.setup(scene_bbox=BOX)
    fresh.fit(Opaque())  # no layers: nothing to fit them to
    assert started == [fresh] and fresh.config.background == "field"
    torch.testing.assert_close(sdf(fresh, vertices), truth, atol=1e-6, rtol=0)


def test_training_improves_test_psnr_and_checkpoint_round_trips(tiny_scene, tmp_path):
    train, test = load_dataset(tiny_scene, "train"), load_dataset(tiny_scene, "test")
    config = NeusConfig.tiny(seconds=600.0)  # the step budget binds: same result on a busy machine
    config.train.max_steps, config.train.batch_rays = 40, 512
    config.upsample_steps, config.resolution = (20,), 64
    field = config.setup(scene_bbox=train.scene_bbox)
    sharpness = float(field.sharpness().detach())
    log = field.fit(train, eval_dataset=test)
    (t0, before), (t1, after) = log["eval"][0], log["eval"][-1]
    assert t0 == 0.0 and t1 > 0 and log["steps"] == 40
    assert after > before + 2.0, log["eval"]
    assert field.grid.resolution == 64 and float(field.sharpness().detach()) > sharpness  # refined; surface sharpened
    field.save(tmp_path / "field.pt")
    loaded = load_field(tmp_path / "field.pt", backend="neus")
    assert isinstance(loaded, NeusField) and loaded.grid.resolution == 64
    assert torch.equal(loaded.occupancy.mask, field.occupancy.mask)
    assert torch.equal(loaded.sharpness(), field.sharpness())
    points = random_points(500, train.scene_bbox)
    dirs = torch.nn.functional.normalize(torch.randn(500, 3), dim=-1)
    for a, b in zip(loaded.query(points, dirs), field.query(points, dirs)):
        torch.testing.assert_close(a, b)
    assert evaluate(loaded, test, RenderConfig()) == pytest.approx(evaluate(field, test, RenderConfig()), abs=1e-4)


def test_checkpoint_of_another_backend_is_refused(tmp_path):
    NeusConfig.tiny().setup(scene_bbox=BOX).save(tmp_path / "neus.pt")
    NerfConfig.tiny().setup(scene_bbox=BOX).save(tmp_path / "nerf.pt")
    with pytest.raises(NerfEditError, match="checkpoint of the 'neus' field backend, not 'nerf'"):
        load_field(tmp_path / "neus.pt", backend="nerf")
    with pytest.raises(NerfEditError, match="checkpoint of the 'nerf' field backend .*not NeusField"):
        NeusField.load(tmp_path / "nerf.pt")
    with pytest.raises(NerfEditError, match="checkpoint of the 'neus' field backend .*not NerfField"):
        NerfField.load(tmp_path / "neus.pt")
