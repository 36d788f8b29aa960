"""Synthetic generator: unlit barycentric colours, depth and alpha against analytic oracles, the written Blender
dataset (layout, exact mesh.ply, determinism) and ground-truth renders of deformed meshes."""

import json

import igl
import numpy as np
import pytest
import torch
import trimesh

from nerfedit_plugin.data.cameras import Cameras, generate_rays, sphere_poses
from nerfedit_plugin.data.datasets import block_mean, load_dataset, read_image, read_transforms
from nerfedit_plugin.data.synthetic import (
    GenerateConfig,
    colorize,
    generate_dataset,
    normalize,
    render_ground_truth,
    render_mesh,
)
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh

SMALL = dict(n_train=4, n_val=1, n_test=3, resolution=24)


def sphere_mesh(radius=0.5, colors=None) -> SurfaceMesh:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return SurfaceMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), colors)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("synthetic") / "cow"
    return generate_dataset(GenerateConfig(out=out, mesh="sample:cow", seed=7, **SMALL))


def test_colours_are_the_barycentric_interpolation_of_vertex_colours():
    """Vertex colours affine in position ⇒ the interpolated colour at a hit is that affine function of the hit
    point o + t·d (an exact oracle for the (u, v) convention), and the background shows where rays miss."""
    a, b = np.array([[0.3, -0.2, 0.1], [0.1, 0.4, -0.3], [-0.2, 0.1, 0.35]]), np.array([0.5, 0.45, 0.5])
    mesh = sphere_mesh()
    mesh.vertex_colors = mesh.vertices @ a.T + b
    cams = Cameras.from_fov(sphere_poses(3, 2.0, seed=1), 20, 16, 0.6)
    rgb, alpha, depth = render_mesh(mesh, cams, background=(0.1, 0.2, 0.3))
    origins, directions = generate_rays(cams)
    hit = np.isfinite(depth)
    assert np.array_equal(alpha, hit.astype(np.float32))  # supersample=1: alpha is the hit mask
    points = (origins + torch.from_numpy(np.where(hit, depth, 0))[..., None] * directions).numpy()
    assert np.allclose(rgb[hit], points[hit] @ a.T + b, atol=2e-6)
    assert np.allclose(rgb[~hit], [0.1, 0.2, 0.3])
    assert 0.2 < hit.mean() < 0.9


def test_depth_and_alpha_match_the_analytic_sphere():
    radius = 0.5
    mesh = sphere_mesh(radius, np.full((2562, 3), 0.5))
    cams = Cameras.from_fov(sphere_poses(2, 2.0, seed=2), 32, 32, 0.7)
    _, alpha, depth = render_mesh(mesh, cams, supersample=2)
    o, d = (x.double().numpy() for x in generate_rays(cams))
    b = (o * d).sum(-1)
    closest = np.sqrt(np.maximum((o * o).sum(-1) - b * b, 0.0))  # distance of the ray line from the centre
    inner = radius * np.cos(np.pi / 5 / 2**4)  # the icosphere lies between this and `radius`
    certain = (closest < inner - 0.02) | (closest > radius + 0.02)  # pixel-centre ray clear of the silhouette
    analytic = -b - np.sqrt(np.maximum(radius**2 - closest**2, 0.0))
    hit = closest < inner - 0.02
    assert np.array_equal(np.isfinite(depth)[certain], hit[certain])
    assert np.allclose(depth[hit], analytic[hit], atol=2e-3)
    # 2x2 supersampling: alpha is 1 deep inside, 0 well outside, fractional only along the silhouette
    pixel = 2.0 / float(cams.fx[0])  # one pixel footprint at the sphere's distance (2)
    assert (alpha[closest < inner - pixel] == 1).all() and (alpha[closest > radius + pixel] == 0).all()
    edge = (alpha > 0) & (alpha < 1)
    assert edge.any() and (np.abs(closest[edge] - radius) < pixel).all()


def test_supersampling_is_the_block_mean_of_the_upscaled_render_and_compositing_is_linear():
    mesh = colorize(sphere_mesh(), seed=1)
    cams = Cameras.from_fov(sphere_poses(2, 2.0, seed=3), 12, 10, 0.6)
    rgb0, alpha, _ = render_mesh(mesh, cams, background=(0, 0, 0), supersample=3)
    fine_rgb, fine_alpha, _ = render_mesh(mesh, cams.upscale(3), background=(0, 0, 0))
    assert np.allclose(alpha, np.stack([block_mean(a, 3) for a in fine_alpha]))
    assert np.allclose(rgb0, np.stack([block_mean(c, 3) for c in fine_rgb]), atol=1e-6)
    rgb1, _, _ = render_mesh(mesh, cams, background=(1.0, 0.5, 0.25), supersample=3)
    assert np.allclose(rgb1 - rgb0, (1 - alpha[..., None]) * np.array([1.0, 0.5, 0.25]), atol=1e-6)


def test_colorize_is_deterministic_quantised_textured_and_smooth():
    mesh = sphere_mesh()
    a, b = colorize(mesh, seed=5), colorize(mesh, seed=5)
    assert np.array_equal(a.vertex_colors, b.vertex_colors)
    assert not np.allclose(a.vertex_colors, colorize(mesh, seed=6).vertex_colors)
    colors = a.vertex_colors
    assert colors.min() >= 0 and colors.max() <= 1 and np.array_equal(np.round(colors * 255) / 255, colors)
    assert colors.std(0).min() > 0.05  # textured, not flat
    edges = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    slope = np.abs(colors[edges[:, 0]] - colors[edges[:, 1]]).max(1) / np.linalg.norm(
        mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]], axis=1
    )
    assert slope.max() < 25.0  # per unit length of a unit-size object: < 0.25 per pixel at 100 px


def test_generated_dataset_layout_cameras_and_exact_mesh(dataset):
    for split, n in (("train", 4), ("val", 1), ("test", 3)):
        ds = load_dataset(dataset, split, background=(0.0, 0.0, 0.0))
        assert ds.images.shape == (n, 24, 24, 3) and ds.alpha.shape == (n, 24, 24)
        assert torch.allclose(ds.cameras.centers.norm(dim=1), torch.full((n,), 2.5))
        assert [p.name for p in ds.image_paths] == [f"r_{i}.png" for i in range(n)]
    meta = json.loads((dataset / "transforms_test.json").read_text())
    assert meta["supersample"] == 2 and meta["w"] == 24 and "camera_angle_x" in meta
    mesh = SurfaceMesh.load(dataset / "mesh.ply")
    cow = SurfaceMesh.load("sample:cow")
    expected = normalize(cow.with_vertices(cow.vertices[:, [0, 2, 1]] * [1, -1, 1]))  # y-up → z-up
    assert np.array_equal(mesh.vertices, expected.vertices)  # exact: normalise rounds to float32 as PLY stores
    assert np.array_equal(mesh.vertex_colors, colorize(expected, 7).vertex_colors)
    extent = mesh.vertices.max(0) - mesh.vertices.min(0)
    assert np.isclose(extent.max(), 1.0, atol=1e-6)
    assert np.allclose(mesh.vertices.max(0), -mesh.vertices.min(0), atol=1e-6)
    aabb = np.array(meta["aabb"])
    assert (aabb[0] < mesh.vertices.min(0)).all() and (aabb[1] > mesh.vertices.max(0)).all()
    assert (dataset / "config.yml").is_file()


def test_generated_images_agree_with_rays_through_the_mesh(dataset):
    """Rays from the dataset's cameras: where the pixel-centre ray has depth t, o + t·d lies on the mesh (libigl
    distance, an independent oracle); hits have alpha > 0, misses alpha < 1; the PNG alpha is the rendered one."""
    mesh = SurfaceMesh.load(dataset / "mesh.ply")
    ds = load_dataset(dataset, "test")
    rgb, alpha, depth = render_mesh(mesh, ds.cameras, supersample=2)
    o, d = generate_rays(ds.cameras)
    hit = np.isfinite(depth)
    points = (o + torch.from_numpy(np.where(hit, depth, 0))[..., None] * d).numpy()[hit]
    sq, _, _ = igl.point_mesh_squared_distance(points, mesh.vertices, mesh.faces)
    assert np.sqrt(sq).max() < 1e-5
    assert (alpha[hit] > 0).all() and (alpha[~hit] < 1).all()
    assert (alpha == 1).any() and (alpha == 0).any()
    assert np.abs(ds.alpha.numpy() - alpha).max() <= 0.5 / 255 + 1e-6
    assert np.abs(ds.images.numpy() - rgb).max() <= 1.0 / 255 + 1e-6  # white background both ways


def test_identity_ground_truth_reproduces_the_test_images_exactly(dataset, tmp_path):
    mesh = SurfaceMesh.load(dataset / "mesh.ply")
    paths = render_ground_truth(mesh, mesh.vertices, dataset / "transforms_test.json", tmp_path / "gt")
    assert [p.name for p in paths] == ["r_0.png", "r_1.png", "r_2.png"]
    for path in paths:
        gt_rgb, gt_alpha = read_image(path)
        ds_rgb, ds_alpha = read_image(dataset / "test" / path.name)
        assert np.array_equal(gt_rgb, ds_rgb) and np.array_equal(gt_alpha, ds_alpha)
    with pytest.raises(NerfEditError, match="gt: output folder exists"):
        render_ground_truth(mesh, mesh.vertices, dataset / "transforms_test.json", tmp_path / "gt")


def test_ground_truth_of_a_translated_mesh_equals_moving_the_cameras_back(dataset, tmp_path):
    mesh = SurfaceMesh.load(dataset / "mesh.ply")
    shift = np.array([0.04, -0.03, 0.05], dtype=np.float32).astype(np.float64)
    paths = render_ground_truth(mesh, mesh.vertices + shift, dataset / "transforms_test.json", tmp_path / "gt")
    cams = read_transforms(dataset / "transforms_test.json").cameras
    c2w = cams.c2w.clone()
    c2w[:, :3, 3] -= torch.from_numpy(shift).float()
    moved = Cameras(c2w, cams.fx, cams.fy, cams.cx, cams.cy, cams.width, cams.height)
    _, alpha, _ = render_mesh(mesh, moved, background=(0, 0, 0), supersample=2)
    _, still, _ = render_mesh(mesh, cams, background=(0, 0, 0), supersample=2)
    gt_alpha = np.stack([read_image(p)[1] for p in paths])
    assert np.abs(gt_alpha - alpha).mean() < 0.01 < np.abs(gt_alpha - still).mean()
    with pytest.raises(NerfEditError, match=r"deformed vertices: expected shape \("):
        render_ground_truth(mesh, mesh.vertices[:-1], dataset / "transforms_test.json", tmp_path / "gt2")


def test_generation_is_deterministic_by_seed(tmp_path):
    config = dict(mesh=str(tmp_path / "sphere.ply"), n_train=2, n_val=1, n_test=1, resolution=16)
    sphere_mesh().save(tmp_path / "sphere.ply")
    a = generate_dataset(GenerateConfig(out=tmp_path / "a", seed=1, **config))
    b = generate_dataset(GenerateConfig(out=tmp_path / "b", seed=1, **config))
    c = generate_dataset(GenerateConfig(out=tmp_path / "c", seed=2, **config))
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name != "config.yml")
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file() and p.name != "config.yml")
    assert all((a / f).read_bytes() == (b / f).read_bytes() for f in files)
    assert (a / "train/r_0.png").read_bytes() != (c / "train/r_0.png").read_bytes()
    assert (a / "transforms_train.json").read_text() != (c / "transforms_train.json").read_text()


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(n_train=0), "n_train: expected a positive integer"),
        (dict(resolution=12.5), "resolution: expected a positive integer"),
        (dict(radius=0.3), "radius: 0.3 puts the cameras inside"),
        (dict(fov_degrees=190.0), "fov_degrees: expected degrees"),
        (dict(up_axis="w"), "up_axis: expected 'y' or 'z'"),
        (dict(mesh="sample:teapot"), "sample:teapot: unknown sample mesh"),
        (dict(mesh="nowhere.ply"), "nowhere.ply: mesh file not found"),
    ],
)
def test_bad_generate_configs_are_rejected_before_writing(tmp_path, change, message):
    config = GenerateConfig(out=tmp_path / "out", **{**dict(mesh="sample:bone", **SMALL), **change})
    with pytest.raises(NerfEditError, match=message):
        generate_dataset(config)
    assert not (tmp_path / "out").exists()


def test_existing_output_is_not_overwritten_silently(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("x")
    config = GenerateConfig(out=tmp_path / "out", mesh="sample:bone", n_train=1, n_val=1, n_test=1, resolution=8)
    with pytest.raises(NerfEditError, match="output folder exists"):
        generate_dataset(config)
    config.overwrite = True
    generate_dataset(config)
    assert not (tmp_path / "out" / "keep.txt").exists() and (tmp_path / "out" / "transforms_val.json").is_file()
