"""A mesh of Gaussian splats (TSDF fusion of their depth, :mod:`nerfedit_plugin.fields.splats.extract`): flat Gaussians
on a known surface give that surface back with its colour; faint Gaussians and bad levels get one clear error;
``nerfedit extract`` on a splat run made from a file writes ``mesh.ply``."""

import numpy as np
import pytest
import trimesh

from nerfedit_plugin.cli import main
from nerfedit_plugin.fields.splats.extract import fuse_mesh
from nerfedit_plugin.fields.splats.files import write_ply
from nerfedit_plugin.fields.splats.model import SplatModel, surface_model
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.run import open_run

BOX = np.array([[-1.3, -1.3, -1.3], [1.3, 1.3, 1.3]])


@pytest.fixture(scope="module")
def ellipsoid() -> trimesh.Trimesh:
    """An ellipsoid of semi-axes 1, 0.8, 0.6, coloured orange."""
    mesh = trimesh.creation.icosphere(subdivisions=4)
    mesh.vertices *= [1.0, 0.8, 0.6]
    mesh.visual.vertex_colors = np.tile([230, 120, 30, 255], (len(mesh.vertices), 1))
    return mesh


def test_flat_gaussians_on_a_surface_give_it_back_with_its_colour(ellipsoid):
    model = surface_model(ellipsoid, 12000, seed=3, radius=0.04)
    mesh = fuse_mesh(model, BOX, resolution=48)
    assert ((mesh.vertices >= BOX[0]) & (mesh.vertices <= BOX[1])).all()
    source = raycast.raycasting_scene(np.asarray(ellipsoid.vertices), np.asarray(ellipsoid.faces))
    there = raycast.distance(source, mesh.vertices)
    back = raycast.distance(raycast.raycasting_scene(mesh.vertices, mesh.faces), ellipsoid.sample(4000, seed=1))
    voxel = 2.6 / 48  # the depth of a pixel is that of the means of the Gaussians it sees: ~1 pixel too near
    assert np.median(there) < 1.5 * voxel and np.median(back) < 1.5 * voxel, (np.median(there), np.median(back))
    assert there.max() < 4 * voxel and back.max() < 4 * voxel, (there.max(), back.max())
    assert mesh.vertex_colors is not None
    colour = np.median(mesh.vertex_colors, axis=0)
    assert np.abs(colour - np.array([230, 120, 30]) / 255).max() < 0.08, colour
    assert len(SurfaceMesh(mesh.vertices, mesh.faces).largest_component().faces) > 0.95 * len(mesh.faces)


def test_faint_gaussians_and_bad_levels_are_errors(ellipsoid):
    model = surface_model(ellipsoid, 2000, seed=3, radius=0.04)
    faint = SplatModel(model.means, model.quats, model.log_scales, np.full(len(model), -8.0, np.float32), model.sh)
    with pytest.raises(ValueError, match="opacity 0.5"):
        fuse_mesh(faint, BOX, resolution=16)
    for level in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match="no opacity in"):
            fuse_mesh(model, BOX, resolution=16, level=level)


def test_extract_writes_the_mesh_of_a_splat_run(tmp_path, ellipsoid):
    write_ply(surface_model(ellipsoid, 6000, seed=4, radius=0.05), tmp_path / "model.ply")
    run = tmp_path / "run"
    main(["train", "--field", "splats", "--data", str(tmp_path / "model.ply"), "--out", str(run)])
    main(["extract", "--run", str(run), "--resolution", "40"])
    mesh = SurfaceMesh.load(run / "mesh.ply")
    box = open_run(run).field().scene_bbox.double().numpy()
    source = raycast.raycasting_scene(np.asarray(ellipsoid.vertices), np.asarray(ellipsoid.faces))
    assert np.median(raycast.distance(source, mesh.vertices)) < 1.5 * (box[1] - box[0]).max() / 40
