"""The ``mesh`` field: exact point queries, the mesh back unchanged, renders equal to the synthetic generator's, and
(as the oracle of ray bending) edited renders that match ground-truth renders of the deformed mesh."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.data.synthetic import GenerateConfig, bend, colorize, generate_dataset, render_mesh
from nerfedit_plugin.edit.lift import Lift
from nerfedit_plugin.edit.proxy import TetProxy, embed_points
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.mesh_field import MeshField, MeshFieldConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.render.renderer import RenderConfig, render_image
from nerfedit_plugin.training.metrics import psnr


@pytest.fixture(scope="module")
def sphere() -> SurfaceMesh:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    return colorize(SurfaceMesh(mesh.vertices, mesh.faces), seed=1)


def test_query_is_the_inside_test_and_the_closest_surface_colour(sphere):
    field = MeshField.from_mesh(sphere, MeshFieldConfig(density=123.0))
    rng = np.random.default_rng(0)
    points = torch.from_numpy(rng.uniform(-0.7, 0.7, (4000, 3))).float()
    radius = points.norm(dim=1)
    clear = (radius - 0.5).abs() > 0.02  # the polyhedron lies within 0.013 of the sphere
    density, _ = field.query(points, points)
    assert torch.equal(density[clear], torch.where(radius[clear] < 0.5, 123.0, 0.0))
    # Points pushed off each face centroid along its normal: the closest surface point is the centroid, whose
    # colour is the mean of the face's three vertex colours (barycentric (1/3, 1/3, 1/3)).
    tri = sphere.vertices[sphere.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    for offset in (0.01, -0.01):
        points = torch.from_numpy(tri.mean(1) + offset * normal).float()
        _, rgb = field.query(points, points)
        expected = sphere.vertex_colors[sphere.faces].mean(1)
        assert np.abs(rgb.numpy() - expected).max() < 1e-5
    _, rgb = field.query(torch.from_numpy(sphere.vertices).float(), torch.zeros(len(sphere.vertices), 3))
    assert np.abs(rgb.numpy() - sphere.vertex_colors).max() < 1e-5


def test_extract_returns_the_mesh_unchanged(sphere):
    mesh = MeshField.from_mesh(sphere).extract_mesh()
    assert np.array_equal(mesh.vertices, sphere.vertices) and np.array_equal(mesh.faces, sphere.faces)
    assert np.abs(mesh.vertex_colors - sphere.vertex_colors).max() < 1e-7  # stored as float32
    assert MeshField.from_mesh(sphere).fit(None) == {}


def test_mesh_without_colours_or_without_a_mesh_is_an_error(sphere):
    with pytest.raises(NerfEditError, match="no vertex colours"):
        MeshField.from_mesh(SurfaceMesh(sphere.vertices, sphere.faces))
    empty = MeshFieldConfig().setup(scene_bbox=torch.tensor([[-1.0] * 3, [1.0] * 3]))
    with pytest.raises(NerfEditError, match="no mesh loaded"):
        empty.query(torch.zeros(1, 3), torch.zeros(1, 3))


def test_renders_what_the_generator_renders(tmp_path):
    """A dataset written by the generator (supersampled, 8-bit PNGs) and the mesh field built from its mesh.ply,
    rendered from the same cameras with the same supersampling: near-identical images."""
    root = generate_dataset(
        GenerateConfig(
            out=tmp_path / "cow", mesh="sample:cow", n_train=3, n_val=1, n_test=1, resolution=64, supersample=2
        )
    )
    dataset = load_dataset(root, "train")
    field = MeshField.from_mesh(SurfaceMesh.load(root / "mesh.ply"))
    config = RenderConfig(n_samples=256, background=dataset.background)
    for i in range(len(dataset)):
        image = render_image(field, dataset.cameras, i, config, supersample=2).numpy()
        truth = dataset.images[i].numpy()
        error = np.abs(image - truth).max(-1)
        assert psnr(image, truth) > 40.0
        assert np.mean(error < 2.5 / 255) > 0.99  # 8-bit quantisation, except a few grazing silhouette rays


def test_ray_bending_reproduces_the_deformed_mesh(capsule, capsule_proxy):
    """The oracle of ray bending: the capsule (subdivided so its surface can bend) is bent by 115°, the proxy is
    lifted from the exact deformed surface, and the mesh field rendered through the bent rays is compared with a
    direct render of the deformed mesh. Volumetric ARAP (tet-arap) reproduces it (≥ 35 dB); the paper's baselines,
    closest-point and knn3 lifts, fold tets and stay several dB lower."""
    vertices, faces = trimesh.remesh.subdivide_to_size(capsule.vertices, capsule.faces, max_edge=0.05)
    mesh = colorize(SurfaceMesh(vertices, faces), seed=4)
    embed_tets, embed_bary = embed_points(capsule_proxy.vertices, capsule_proxy.tets, mesh.vertices)
    assert (embed_tets >= 0).all()  # subdivision points lie on the coarse surface, inside the same proxy
    proxy = TetProxy(capsule_proxy.vertices, capsule_proxy.tets, capsule_proxy.cage, embed_tets, embed_bary)
    bent = bend(mesh.vertices, radius=1.0)
    cams = Cameras.from_fov(look_at(torch.tensor([[0.0, -3.5, 0.3]]), torch.tensor([[0.3, 0.0, 0.0]])), 64, 64, 0.75)
    truth = render_mesh(mesh.with_vertices(bent), cams)[0][0]
    field, config = MeshField.from_mesh(mesh), RenderConfig(n_samples=96)
    methods = ("tet-arap", "closest-point", "knn3")
    lifted = np.concatenate([Lift(proxy, mesh, method)(bent[None])[0] for method in methods])
    deformation = DeformationField(proxy.vertices, proxy.tets, lifted)  # one frame per lift method
    scores = {
        method: psnr(render_image(field, cams, 0, config, deformation=deformation, frame=frame).numpy(), truth)
        for frame, method in enumerate(methods)
    }
    assert scores["tet-arap"] >= 35.0, scores
    assert scores["tet-arap"] >= max(scores["closest-point"], scores["knn3"]) + 5.0, scores


def test_a_mesh_without_colours_trains_with_a_colour_option(sphere, tmp_path, capsys):
    """`nerfedit train --field mesh` refuses a mesh without vertex colours, naming the option that gives it one."""
    from nerfedit_plugin.cli.app import main
    from nerfedit_plugin.pipeline.run import open_run

    SurfaceMesh(sphere.vertices, sphere.faces).save(tmp_path / "plain.ply")
    args = ["train", "--field", "mesh", "--data", str(tmp_path / "plain.ply")]
    assert main([*args, "--out", str(tmp_path / "a")]) == 2
    assert "--field-options.color R G B" in capsys.readouterr().err and not (tmp_path / "a").exists()
    assert main([*args, "--field-options.color", "0.2", "0.4", "0.6", "--out", str(tmp_path / "b")]) == 0
    mesh = open_run(tmp_path / "b").mesh()
    assert np.allclose(mesh.vertex_colors, [0.2, 0.4, 0.6], atol=1 / 255)
    assert main([*args, "--field-options.color", "2", "0", "0", "--out", str(tmp_path / "c")]) == 2
    assert "--field-options.color" in capsys.readouterr().err
