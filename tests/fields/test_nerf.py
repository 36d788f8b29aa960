"""The nerf backend: exact trilinear grid and refinement, a conservative occupancy grid, visual-hull carving that
keeps the object, training that improves PSNR, mesh extraction and checkpoint round trips."""

import math

import numpy as np
import pytest
import torch

from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.fields.encoding import DenseGrid, spherical_harmonics
from nerfedit_plugin.fields.nerf import NerfConfig, NerfField
from nerfedit_plugin.fields.occupancy import silhouette_depths
from nerfedit_plugin.training.trainer import evaluate

BOX = torch.tensor([[-0.5, -0.4, -0.3], [0.5, 0.4, 0.3]])


def random_points(n, box=BOX, seed=0):
    g = torch.Generator().manual_seed(seed)
    return box[0] + torch.rand(n, 3, generator=g) * (box[1] - box[0])


def test_trilinear_reproduces_affine_functions_exactly():
    grid = DenseGrid(BOX, 8, 2)
    a = torch.tensor([[1.0, -2.0], [0.5, 3.0], [-4.0, 0.25]])
    with torch.no_grad():
        grid.table.copy_(grid.vertex_points().reshape(-1, 3) @ a + torch.tensor([0.3, -1.0]))
    points = random_points(1000)
    torch.testing.assert_close(grid(points), points @ a + torch.tensor([0.3, -1.0]), atol=2e-5, rtol=0)
    _, weights = grid.corners(points)
    torch.testing.assert_close(weights.sum(1), torch.ones(1000))
    assert (weights >= 0).all()


def test_upsample_preserves_the_field_exactly():
    grid = DenseGrid(BOX, 4, 3, init=torch.randn(5**3, 3, generator=torch.Generator().manual_seed(1)))
    points = random_points(2000, seed=2)
    before = grid(points).detach()
    grid.upsample()
    assert grid.resolution == 8 and grid.table.shape == (9**3, 3)
    torch.testing.assert_close(grid(points).detach(), before, atol=1e-5, rtol=0)


def test_spherical_harmonics_are_orthonormal():
    d = torch.nn.functional.normalize(torch.randn(200_000, 3, generator=torch.Generator().manual_seed(3)), dim=-1)
    basis = spherical_harmonics(d, 2)
    gram = 4 * math.pi * basis.T @ basis / len(d)  # Monte Carlo ∫ Y_i Y_j dω
    torch.testing.assert_close(gram, torch.eye(9), atol=0.03, rtol=0)


def random_field(seed=0, **overrides) -> NerfField:
    config = NerfConfig(
        resolution=16,
        upsample_steps=(),
        features=4,
        decoder="mlp",
        occupancy_resolution=8,
        occupancy_dilation=0,
        **overrides,
    )
    field = config.setup(scene_bbox=BOX)
    with torch.no_grad():
        field.grid.table[:, 0] = torch.randn(17**3, generator=torch.Generator().manual_seed(seed)) * 3 - 2
    return field


def test_occupancy_never_marks_dense_space_empty():
    field = random_field(occupancy_threshold=20.0)
    field.update_occupancy()
    assert 0.05 < field.occupancy.fraction < 0.95  # a real mix of occupied and empty cells
    points = random_points(200_000, seed=4)
    density, _ = field.query(points, torch.zeros_like(points))
    dense = density > 20.0
    assert dense.any()
    assert field.occupied(points)[dense].all()
    # the bound is tight: every occupied cell holds a grid vertex above the threshold
    assert field.cell_max_density().gt(20.0).eq(field.occupancy.mask).all()


def test_occupancy_is_empty_outside_the_box():
    field = random_field()
    outside = torch.tensor([[0.6, 0.0, 0.0], [0.0, -0.5, 0.0], [0.0, 0.0, 0.31]])
    assert not field.occupied(outside).any()
    assert (field.query(outside, torch.zeros_like(outside))[0] == 0).all()


def test_carving_keeps_every_cell_of_the_object(tiny_scene):
    data = load_dataset(tiny_scene, "train")
    field = NerfConfig.tiny().setup(scene_bbox=data.scene_bbox)
    field.occupancy.carve(data.cameras, silhouette_depths(data.alpha > 0))
    assert field.occupancy.fraction < 0.6  # the hull is much smaller than the box
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    mesh = SurfaceMesh.load(tiny_scene / "mesh.ply")
    assert field.occupied(torch.from_numpy(mesh.vertices).float()).all()


def test_training_improves_test_psnr_and_checkpoint_round_trips(tiny_scene, tmp_path):
    from nerfedit_plugin.fields.checkpoint import load_field
    from nerfedit_plugin.render.renderer import RenderConfig

    train, test = load_dataset(tiny_scene, "train"), load_dataset(tiny_scene, "test")
    config = NerfConfig.tiny(seconds=120.0)  # the step budget binds: same result on a busy machine
    config.train.max_steps, config.train.clock = 80, "cpu"  # CPU seconds: a loaded machine does not eat the budget
    config.upsample_steps = (20,)
    config.resolution = 64
    field = config.setup(scene_bbox=train.scene_bbox)
    log = field.fit(train, eval_dataset=test)
    (t0, before), (t1, after) = log["eval"][0], log["eval"][-1]
    assert t0 == 0.0 and t1 > 0 and log["steps"] == 80
    assert after > before + 3.0, log["eval"]
    assert field.grid.resolution == 64  # refined coarse to fine
    field.save(tmp_path / "field.pt")
    loaded = load_field(tmp_path / "field.pt", backend="nerf")
    assert isinstance(loaded, NerfField) and loaded.grid.resolution == 64
    assert torch.equal(loaded.occupancy.mask, field.occupancy.mask)
    points = random_points(500, train.scene_bbox)
    dirs = torch.nn.functional.normalize(torch.randn(500, 3), dim=-1)
    for a, b in zip(loaded.query(points, dirs), field.query(points, dirs)):
        torch.testing.assert_close(a, b)
    assert evaluate(loaded, test, RenderConfig()) == pytest.approx(evaluate(field, test, RenderConfig()), abs=1e-4)


def test_extract_mesh_of_a_ball():
    field = NerfConfig(resolution=32, upsample_steps=(), occupancy_resolution=0).setup(scene_bbox=BOX)
    radius = 0.25
    with torch.no_grad():
        inside = field.grid.vertex_points().reshape(-1, 3).norm(dim=1) < radius
        field.grid.table[:, 0] = torch.where(inside, 20.0, -20.0)
    mesh = field.extract_mesh(resolution=64, level=50.0)
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert abs(r.mean() - radius) < 0.03 and r.std() < 0.02
    v = mesh.vertices[mesh.faces]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert (np.einsum("ij,ij->i", normals, v.mean(1)) > 0).mean() > 0.99  # faces wind outward
    assert mesh.vertex_colors.shape == (len(mesh.vertices), 3)
    assert ((mesh.vertex_colors >= 0) & (mesh.vertex_colors <= 1)).all()
    with pytest.raises(ValueError, match="outside the range"):
        field.extract_mesh(resolution=16, level=1e9)


def test_occupancy_lookup_matches_the_cell_of_each_point():
    from nerfedit_plugin.fields.occupancy import OccupancyGrid

    grid = OccupancyGrid(BOX, 5)
    grid.mask.copy_(torch.rand(5, 5, 5, generator=torch.Generator().manual_seed(5)) > 0.5)
    points = torch.cat([random_points(3000, BOX * 1.2, seed=6), BOX, BOX.mean(0, keepdim=True)])  # + the corners
    u = (points - BOX[0]) / (BOX[1] - BOX[0]) * 5
    inside = ((u >= 0) & (u <= 5)).all(1)
    cell = u.floor().clamp(0, 4).long()
    expected = torch.tensor([bool(grid.mask[tuple(c)]) for c in cell.tolist()]) & inside
    assert torch.equal(grid.occupied(points), expected) and inside.any() and (~inside).any()


def test_view_dependence_follows_the_colour_decoder():
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert NerfField(NerfConfig.tiny(), box).view_dependent  # MLP on spherical harmonics of degree 1
    assert not NerfField(NerfConfig.tiny(sh_degree=0), box).view_dependent
    assert not NerfField(NerfConfig(), box).view_dependent  # the default: direct colour only


GRID_ONLY = {"upsample_steps": (), "occupancy_resolution": 0}
"""A grid of any resolution: no refinement, no occupancy grid."""


def test_appearance_tv_is_the_mean_squared_difference_along_the_edges_of_each_points_cell():
    """Against a brute force over the 12 edges of each point's cell (features only, not the density); constant
    features have none."""
    box = torch.tensor([[-1.0, -0.5, 0.0], [1.0, 0.5, 2.0]])
    field = NerfConfig.tiny(resolution=6, features=3, **GRID_ONLY).setup(scene_bbox=box)
    with torch.no_grad():
        field.grid.table.normal_(0.0, 1.0, generator=torch.Generator().manual_seed(0))
    points = box[0] + torch.rand(50, 3, generator=torch.Generator().manual_seed(1)) * (box[1] - box[0])
    volume = field.grid.vertex_values()[1:]  # (C, N+1, N+1, N+1)
    cells = ((points - box[0]) / (box[1] - box[0]) * 6).floor().long().clamp_max(5)
    squares = []
    for i, j, k in cells.tolist():
        for axis in range(3):
            for a in (0, 1):
                for b in (0, 1):
                    start = [i, j, k]
                    others = [d for d in range(3) if d != axis]
                    start[others[0]] += a
                    start[others[1]] += b
                    end = list(start)
                    end[axis] += 1
                    squares.append((volume[:, end[0], end[1], end[2]] - volume[:, start[0], start[1], start[2]]) ** 2)
    torch.testing.assert_close(field.appearance_tv(points), torch.stack(squares).mean(), rtol=1e-6, atol=0)
    with torch.no_grad():
        field.grid.table[:, 1:] = 0.7
    assert float(field.appearance_tv(points)) == 0.0
