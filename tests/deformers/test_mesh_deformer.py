"""The ``mesh`` deformer: frames read from meshes with the rest mesh's vertex order; bad files rejected."""

import json

import numpy as np
import pytest
import trimesh

from deformers.mesh import MeshConfig
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.testing import parametrize_with_checks


@pytest.fixture
def rest(tmp_path):
    mesh = SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=2))
    mesh.save(tmp_path / "rest.ply")
    return mesh


def bind(tmp_path, rest, spec):
    (tmp_path / "edit.json").write_text(json.dumps(spec))
    deformer = MeshConfig().setup()
    deformer.bind(rest, load_edit_spec(tmp_path / "edit.json", deformer.spec_keys))
    return deformer.deform()


def test_single_file_and_interpolated_frames(tmp_path, rest):
    moved = rest.vertices * [1.0, 2.0, 0.5] + 0.25
    rest.with_vertices(moved).save(tmp_path / "edited.obj")
    frames = bind(tmp_path, rest, {"deformed": "edited.obj"})
    assert frames.shape == (1, rest.n_vertices, 3) and np.allclose(frames[0], moved)
    frames = bind(tmp_path, rest, {"deformed": "edited.obj", "frames": 3})
    assert np.allclose(frames[0], rest.vertices) and np.allclose(frames[1], (rest.vertices + moved) / 2)


def test_glob_gives_one_frame_per_file_in_order(tmp_path, rest):
    (tmp_path / "poses").mkdir()
    for i in range(3):
        rest.with_vertices(rest.vertices + i).save(tmp_path / "poses" / f"p{i}.ply")
    frames = bind(tmp_path, rest, {"deformed": "poses/*.ply"})
    assert frames.shape[0] == 3 and all(np.allclose(frames[i], rest.vertices + i) for i in range(3))


def test_wrong_vertex_count_and_connectivity_are_errors(tmp_path, rest):
    SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=1)).save(tmp_path / "small.ply")
    with pytest.raises(NerfEditError, match=r"small.ply: 42 vertices, the rest mesh has 162"):
        bind(tmp_path, rest, {"deformed": "small.ply"})
    SurfaceMesh(rest.vertices, rest.faces[:, [0, 2, 1]]).save(tmp_path / "flipped.ply")
    with pytest.raises(NerfEditError, match="flipped.ply: connectivity differs"):
        bind(tmp_path, rest, {"deformed": "flipped.ply"})
    with pytest.raises(NerfEditError, match="matches no file"):
        bind(tmp_path, rest, {"deformed": "none/*.ply"})


@parametrize_with_checks(
    MeshConfig(),
    edit={"deformed": "edited.ply", "frames": 2},
    identity_edit={"deformed": "same.ply"},
    rigid_edit={"deformed": "rigid.ply"},
)
def test_conformance_kit(check, tmp_path, rest):
    rot = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    rest.with_vertices(rest.vertices * [1.0, 1.3, 0.8]).save(tmp_path / "edited.ply")
    rest.save(tmp_path / "same.ply")
    rest.with_vertices(rest.vertices @ rot.T + 0.5).save(tmp_path / "rigid.ply")
    check(rest=rest, base_dir=tmp_path)
