"""``nerfedit extract --drop-plane / --drop-floaters``: the run's mesh cleaned of a scene's floor and floaters (the
extraction itself replaced by the generated scene, so no field is trained), the default output unchanged."""

import numpy as np
import pytest
import yaml
from scene_meshes import floor_scene

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.run import Run

SCENE = floor_scene()


class SceneField:
    """Stands in for a trained field whose marching cubes give the scene."""

    def extract_mesh(self, resolution, level):
        return SCENE.mesh


@pytest.fixture
def run(tmp_path, monkeypatch):
    """A trained field's run whose extraction gives the scene."""
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "config.yml").write_text(yaml.safe_dump({"field": "nerf", "data": ".", "field_config": {}}))
    monkeypatch.setattr(Run, "field", lambda self, device=None, registry=None: SceneField())
    return folder, None


def test_default_output_is_the_extraction_unchanged(run):
    folder, _ = run
    assert main(["extract", "--run", str(folder)]) == 0
    assert SurfaceMesh.load(folder / "mesh.ply").n_vertices == SCENE.mesh.n_vertices - len(SCENE.floater)


def test_drop_plane_leaves_the_objects(run):
    folder, _ = run
    assert main(["extract", "--run", str(folder), "--drop-plane"]) == 0
    mesh, boxes = SurfaceMesh.load(folder / "mesh.ply"), np.concatenate(SCENE.boxes)
    # the floaters went with the largest part: the floor holds the objects
    np.testing.assert_allclose(mesh.vertices, SCENE.mesh.vertices[boxes])
    np.testing.assert_allclose(mesh.vertex_colors, SCENE.mesh.vertex_colors[boxes], atol=1 / 255)
    assert mesh.component_labels().max() + 1 == 2


def test_drop_floaters_keeps_parts_above_the_fraction(run):
    folder, _ = run
    assert main(["extract", "--run", str(folder), "--drop-plane", "--drop-floaters", "0.5"]) == 0
    # every part extracted, then the small ones dropped
    assert SurfaceMesh.load(folder / "mesh.ply").n_vertices == sum(len(box) for box in SCENE.boxes)
    assert main(["extract", "--run", str(folder), "--drop-floaters", "0", "--overwrite"]) == 0
    assert SurfaceMesh.load(folder / "mesh.ply").n_vertices == SCENE.mesh.n_vertices  # 0 keeps every part


def test_a_mesh_fields_mesh_is_not_cleaned(tmp_path, capsys):
    SCENE.mesh.save(tmp_path / "scene.ply")
    assert main(["train", "--field", "mesh", "--data", str(tmp_path / "scene.ply"), "--out", str(tmp_path / "r")]) == 0
    before = (tmp_path / "r" / "mesh.ply").read_bytes()
    capsys.readouterr()
    assert main(["extract", "--run", str(tmp_path / "r"), "--drop-plane"]) == 2
    assert "the mesh field's mesh is its field and stays whole" in capsys.readouterr().err
    assert (tmp_path / "r" / "mesh.ply").read_bytes() == before


def test_bad_fraction_is_an_option_error(tmp_path, capsys):
    assert main(["extract", "--run", str(tmp_path), "--drop-floaters", "1.5"]) == 2
    assert "--drop-floaters: must be in [0, 1], got 1.5" in capsys.readouterr().err


def test_the_clean_up_runs_before_the_one_write(run, monkeypatch):
    """extract_mesh cleans the extraction before it writes mesh.ply: an interrupt cannot leave the uncleaned mesh
    there, and a clean-up that fails leaves the previous file as it was."""
    from nerfedit_plugin.errors import NerfEditError
    from nerfedit_plugin.pipeline.extract import extract_mesh
    from nerfedit_plugin.pipeline.run import open_run

    folder, _ = run
    assert main(["extract", "--run", str(folder)]) == 0
    before = (folder / "mesh.ply").read_bytes()
    square = SurfaceMesh(np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    monkeypatch.setattr(SceneField, "extract_mesh", lambda self, resolution, level: square)  # all floor
    with pytest.raises(NerfEditError, match="nothing is left after the clean-up"):
        extract_mesh(open_run(folder), overwrite=True, drop_plane=True)
    assert (folder / "mesh.ply").read_bytes() == before
