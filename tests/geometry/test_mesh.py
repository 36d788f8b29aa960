"""SurfaceMesh files: PLY files read through Open3D give what trimesh reads, keep the file's vertex order, and
files Open3D reads no triangles from are left to trimesh."""

import numpy as np
import open3d as o3d
import pytest
import trimesh

from nerfedit_plugin.geometry.mesh import SurfaceMesh, _read_ply_open3d

RNG = np.random.default_rng(0)
MESH = SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=2))
COLORS = RNG.integers(0, 256, (MESH.n_vertices, 3)) / 255.0


def _by_trimesh(path):
    return SurfaceMesh.from_trimesh(trimesh.load(path, process=False, force="mesh", maintain_order=True))


def _equal(a, b):
    colors = (a.vertex_colors is None and b.vertex_colors is None) or (
        a.vertex_colors is not None and b.vertex_colors is not None and np.array_equal(a.vertex_colors, b.vertex_colors)
    )
    return np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces) and colors


def _open3d_normals(mesh, path):
    o3d_mesh = mesh.to_open3d()
    o3d_mesh.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(path), o3d_mesh, write_vertex_normals=True)


WRITERS = {
    "open3d float64": lambda path: MESH.save(path),
    "open3d colours": lambda path: SurfaceMesh(MESH.vertices, MESH.faces, COLORS).save(path),
    "open3d uniform colour": lambda path: SurfaceMesh(
        MESH.vertices, MESH.faces, np.full((MESH.n_vertices, 3), 0.5)
    ).save(path),
    "open3d normals": lambda path: _open3d_normals(MESH, path),
    "trimesh float32": lambda path: MESH.to_trimesh().export(path),
    "trimesh colours": lambda path: SurfaceMesh(MESH.vertices, MESH.faces, COLORS).to_trimesh().export(path),
}


@pytest.mark.parametrize("writer", WRITERS)
def test_ply_is_read_by_open3d_as_trimesh_reads_it(writer, tmp_path):
    path = tmp_path / "mesh.ply"
    WRITERS[writer](path)
    fast = _read_ply_open3d(path)
    assert fast is not None
    assert _equal(fast, _by_trimesh(path)) and _equal(SurfaceMesh.load(path), fast)


def test_ascii_ply_and_shuffled_vertex_order_are_kept(tmp_path):
    order = RNG.permutation(MESH.n_vertices)
    inverse = np.argsort(order)
    shuffled = SurfaceMesh(MESH.vertices[order], inverse[MESH.faces])
    shuffled.to_trimesh().export(tmp_path / "ascii.ply", encoding="ascii")
    loaded = SurfaceMesh.load(tmp_path / "ascii.ply")  # the text parsed as float64 (trimesh: as its float32 type)
    assert np.allclose(loaded.vertices, shuffled.vertices, atol=1e-6) and np.array_equal(loaded.faces, shuffled.faces)


def test_a_ply_without_triangles_is_left_to_trimesh(tmp_path):
    trimesh.PointCloud(MESH.vertices).export(tmp_path / "points.ply")
    assert _read_ply_open3d(tmp_path / "points.ply") is None
    with pytest.raises(Exception, match="points.ply: no triangles in file"):
        SurfaceMesh.load(tmp_path / "points.ply")


@pytest.mark.parametrize("content", [b"", b"solid x\n", b"pl"])
def test_a_file_that_is_no_ply_is_left_to_trimesh_without_open3d_output(content, tmp_path, capfd):
    """Open3D's RPly would print its own error line before nerfedit's; the magic number is checked first."""
    (tmp_path / "e.ply").write_bytes(content)
    assert _read_ply_open3d(tmp_path / "e.ply") is None
    assert capfd.readouterr() == ("", "")


def test_a_bad_index_in_a_fast_read_file_names_the_file(tmp_path):
    path = tmp_path / "bad.ply"
    SurfaceMesh(MESH.vertices, MESH.faces).save(path)
    data = bytearray(path.read_bytes())
    data[-4:] = np.array([10**6], dtype="<u4").tobytes()  # last corner of the last face out of range
    path.write_bytes(bytes(data))
    with pytest.raises(Exception, match="bad.ply: mesh faces: face"):
        SurfaceMesh.load(path)


def test_referenced_marks_exactly_the_vertices_of_faces():
    """``referenced()`` equals ``np.unique(faces)`` as a mask: a stray vertex (index 2 and the last) is unmarked."""
    vertices = np.random.default_rng(0).normal(size=(7, 3))
    faces = np.array([[0, 1, 3], [3, 4, 5], [1, 4, 0]])
    mask = SurfaceMesh(vertices, faces).referenced()
    assert mask.dtype == bool and np.array_equal(np.flatnonzero(mask), np.unique(faces))


def test_self_intersecting_faces_are_those_across_the_other_part():
    """Two overlapping icospheres as one mesh: every face with corners on both sides of the other sphere crosses it
    (a path from inside to outside meets the surface), and no face farther than its own size from the other sphere
    does; apart, or alone, no face crosses (faces sharing corners do not count); no faces, no crossings."""
    from nerfedit_plugin.geometry import raycast

    sphere = trimesh.creation.icosphere(subdivisions=3)
    assert not SurfaceMesh.from_trimesh(sphere).self_intersecting_faces().any()
    assert SurfaceMesh(sphere.vertices, np.zeros((0, 3), dtype=np.int64)).self_intersecting_faces().shape == (0,)
    for shift, expect_any in ((0.8, True), (2.5, False)):
        other = sphere.copy()
        other.apply_translation([shift, 0.1, 0.0])
        both = SurfaceMesh.from_trimesh(trimesh.util.concatenate([sphere, other]))
        crossing = both.self_intersecting_faces()
        assert crossing.shape == (len(both.faces),) and crossing.any() == expect_any
        n = len(sphere.faces)
        for mine, theirs in ((slice(0, n), other), (slice(n, None), sphere)):
            scene = raycast.raycasting_scene(np.asarray(theirs.vertices), np.asarray(theirs.faces))
            inside = raycast.occupancy(scene, both.vertices[both.faces[mine]].reshape(-1, 3)).reshape(-1, 3)
            straddling = inside.any(axis=1) & ~inside.all(axis=1)
            assert not (straddling & ~crossing[mine]).any()
            centres = both.vertices[both.faces[mine]].mean(axis=1)
            distance = np.abs(np.linalg.norm(centres - theirs.centroid, axis=1) - 1.0)
            assert not (crossing[mine] & (distance > 0.2)).any()  # edges of this sphere are ~0.1


@pytest.mark.parametrize("colors", [None, COLORS])
def test_open3d_and_trimesh_conversions_are_lossless(colors):
    mesh = SurfaceMesh(MESH.vertices, MESH.faces, colors)
    assert _equal(SurfaceMesh.from_open3d(mesh.to_open3d()), mesh)
    back = mesh.to_trimesh()
    assert np.array_equal(back.vertices, mesh.vertices) and np.array_equal(back.faces, mesh.faces)
