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
    assert np.array_equal(bind(tmp_path, rest, {"deformed": "poses/*.ply", "frames": 3}), frames)
    for n in (1, 2):  # an explicit frames that is not the file count (1 included: the contract's frame count)
        with pytest.raises(NerfEditError, match=rf"frames: {n} frame\(s\) but 3 deformed meshes \(leave frames out"):
            bind(tmp_path, rest, {"deformed": "poses/*.ply", "frames": n})


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


def test_mesh_deformer_through_cli_writes_the_mesh_and_the_lifted_proxy(tmp_path, rest):
    """``nerfedit edit --deformer mesh --lift closest-point`` (a coarse proxy, to be quick): the deformed mesh is the
    edited file (the rest connectivity), the report names the lift, and deformation.npz holds the proxy moved by
    the closest-point lift of the non-rigid map x ↦ (x, 1.3 y, 0.8 z): at a proxy vertex outside the (convex) mesh,
    the displacement (0, 0.3 q_y, −0.2 q_z) of its closest surface point q (found here with trimesh, not Open3D)."""
    from nerfedit_plugin.bending.deformation_field import DeformationField
    from nerfedit_plugin.cli.app import main

    stretch = np.array([1.0, 1.3, 0.8])
    rest.with_vertices(rest.vertices * stretch).save(tmp_path / "edited.ply")
    (tmp_path / "edit.json").write_text(json.dumps({"deformed": "edited.ply"}))
    out = tmp_path / "out"
    args = ["edit", "--mesh", str(tmp_path / "rest.ply"), "--edit", str(tmp_path / "edit.json"), "--out", str(out)]
    args += ["--deformer", "mesh", "--lift", "closest-point", "--cache-dir", str(tmp_path / "cache")]
    assert main([*args, "--proxy.edge-length-fac", "0.25", "--proxy.cage-faces", "200"]) == 0
    deformed = SurfaceMesh.load(out / "deformed_mesh.ply")
    np.testing.assert_array_equal(deformed.faces, rest.faces)
    np.testing.assert_allclose(deformed.vertices, rest.vertices * stretch, rtol=0, atol=1e-6)
    report = json.loads((out / "report.json").read_text())
    assert (report["deformer"], report["lift"], report["frames"], len(report["per_frame"])) == (
        "MeshDeformer",
        "closest-point",
        1,
        1,
    )
    assert json.loads((out / "edit.json").read_text()) == {"deformed": str(tmp_path / "edited.ply")}  # runs anywhere
    field = DeformationField.load(out / "deformation.npz")
    assert field.n_frames == 1 and len(field.rest_vertices) == report["proxy"]["vertices"]
    proxy, displacement = field.rest_vertices, field.deformed_vertices[0] - field.rest_vertices
    triangles = rest.vertices[rest.faces]  # brute force: each proxy vertex against every triangle
    pairs = trimesh.triangles.closest_point(np.tile(triangles, (len(proxy), 1, 1)), np.repeat(proxy, len(triangles), 0))
    pairs = pairs.reshape(len(proxy), len(triangles), 3)
    nearest = np.linalg.norm(pairs - proxy[:, None], axis=-1).argmin(1)
    closest = pairs[np.arange(len(proxy)), nearest]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])  # outward (convex mesh)
    outside = (np.einsum("fd,nfd->nf", normals, proxy[:, None] - triangles[None, :, 0]) > 0).any(1)
    outside &= np.linalg.norm(closest - proxy, axis=1) > 1e-3
    assert outside.sum() > 30
    expected = closest * (stretch - 1)
    np.testing.assert_allclose(displacement[outside], expected[outside], rtol=0, atol=1e-5)
    assert np.abs(displacement[:, 0]).max() < 1e-9  # every blend of zero x-displacements
