"""Run folders: a mesh field's run holds its mesh.ply at once; extract on runs that have a mesh."""

import numpy as np
import pytest
import yaml

from nerfedit_plugin.data.synthetic import colorize
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.mesh_field import MeshFieldConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.extract import extract_mesh
from nerfedit_plugin.pipeline.run import open_run
from nerfedit_plugin.pipeline.train import train_run


@pytest.fixture
def mesh_run(tmp_path, capsule):
    colorize(capsule, 0).save(tmp_path / "capsule.ply")
    run, log = train_run(
        "mesh", MeshFieldConfig(), tmp_path / "capsule.ply", tmp_path / "run", device="cpu", record={"what": "recorded"}
    )
    assert log == {}
    return run


def test_mesh_run_holds_its_mesh_in_vertex_order(mesh_run, tmp_path):
    assert mesh_run.exact_mesh and mesh_run.mesh_path.is_file()
    mesh, source = mesh_run.mesh(), SurfaceMesh.load(tmp_path / "capsule.ply")
    assert np.array_equal(mesh.vertices, source.vertices) and np.array_equal(mesh.faces, source.faces)
    assert np.array_equal(mesh.vertex_colors, source.vertex_colors)
    config = yaml.safe_load((mesh_run.path / "config.yml").read_text())
    assert config["field"] == "mesh" and config["data"] == "../capsule.ply"
    assert config["command"] == {"what": "recorded"}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".run")]  # written in one atomic stage


def test_extract_keeps_a_mesh_runs_mesh_and_rewrites_it_on_overwrite(mesh_run):
    before = mesh_run.mesh_path.read_bytes()
    assert extract_mesh(mesh_run) == mesh_run.mesh_path  # nothing to extract: the field is the mesh
    assert mesh_run.mesh_path.read_bytes() == before
    assert extract_mesh(mesh_run, overwrite=True, device="cpu") == mesh_run.mesh_path
    assert mesh_run.mesh_path.read_bytes() == before


def test_a_mesh_run_without_mesh_ply_still_gives_its_mesh(mesh_run, tmp_path):
    """Runs of the mesh field written before runs held mesh.ply."""
    mesh_run.mesh_path.unlink()
    assert np.array_equal(open_run(mesh_run.path).mesh().vertices, SurfaceMesh.load(tmp_path / "capsule.ply").vertices)
    assert extract_mesh(mesh_run, device="cpu") == mesh_run.mesh_path and mesh_run.mesh_path.is_file()


def test_extract_refuses_to_replace_a_trained_fields_mesh(tmp_path, capsule):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yml").write_text(yaml.safe_dump({"field": "nerf", "data": ".", "field_config": {}}))
    capsule.save(run / "mesh.ply")
    opened = open_run(run)
    assert not opened.exact_mesh
    with pytest.raises(NerfEditError, match="exists \\(pass --overwrite"):
        extract_mesh(opened)
