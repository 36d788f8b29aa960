"""Scene clean-up: the floor found as the largest plane (exactly its vertices, the same twice), connected parts,
sub-meshes and floaters dropped, on a generated floor with two boxes standing on it and a floater."""

import numpy as np
import pytest
from scene_meshes import floor_scene

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.cleanup import drop_floaters, largest_plane
from nerfedit_plugin.geometry.mesh import SurfaceMesh


@pytest.fixture(scope="module")
def scene():
    return floor_scene()


def test_largest_plane_is_the_floor_with_exactly_its_vertices(scene):
    plane, on = largest_plane(scene.mesh)
    np.testing.assert_allclose(plane, [0, 0, 1, 0], atol=1e-12)  # normal up: the boxes stand above it
    np.testing.assert_array_equal(np.flatnonzero(on), np.sort(scene.floor))


def test_largest_plane_is_deterministic(scene):
    first, again = largest_plane(scene.mesh), largest_plane(scene.mesh)
    np.testing.assert_array_equal(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])


def test_largest_plane_of_a_noisy_moved_floor():
    """A floor with noise below the distance, the scene rotated and moved far from the origin: the same vertices."""
    scene = floor_scene()
    rng = np.random.default_rng(0)
    vertices = scene.mesh.vertices.copy()
    vertices[scene.floor, 2] += rng.uniform(-2e-3, 2e-3, len(scene.floor))
    angle = 0.3
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    moved = SurfaceMesh(vertices @ rotation.T + 1e4, scene.mesh.faces)
    plane, on = largest_plane(moved, distance=5e-3)
    np.testing.assert_array_equal(np.flatnonzero(on), np.sort(scene.floor))
    np.testing.assert_allclose(plane[:3], rotation[:, 2], atol=1e-2)


def test_largest_plane_rejects_bad_input(scene):
    with pytest.raises(NerfEditError, match="at least 3 vertices"):
        largest_plane(SurfaceMesh(np.zeros((2, 3)), np.zeros((0, 3))))
    with pytest.raises(NerfEditError, match="distance must be > 0"):
        largest_plane(scene.mesh, distance=0.0)


def test_components_before_and_after_dropping_the_floor(scene):
    labels = scene.mesh.component_labels()
    assert labels.max() + 1 == 2  # floor with the boxes, and the floater
    assert len(np.unique(labels[scene.floater])) == 1 and labels[scene.floater[0]] != labels[scene.boxes[0][0]]
    _, on = largest_plane(scene.mesh)
    objects, index = scene.mesh.submesh(~on)
    parts = objects.component_labels()
    assert parts.max() + 1 == 3  # two boxes and the floater
    for box in scene.boxes:
        assert len(np.unique(parts[index[box]])) == 1 and np.count_nonzero(parts == parts[index[box[0]]]) == len(box)


def test_submesh_keeps_order_colours_and_maps_indices(scene):
    keep = np.zeros(scene.mesh.n_vertices, dtype=bool)
    keep[scene.boxes[1]] = True
    part, index = scene.mesh.submesh(keep)
    np.testing.assert_array_equal(part.vertices, scene.mesh.vertices[scene.boxes[1]])
    np.testing.assert_array_equal(part.vertex_colors, scene.mesh.vertex_colors[scene.boxes[1]])
    np.testing.assert_array_equal(index[scene.boxes[1]], np.arange(len(scene.boxes[1])))
    assert (index[~keep] == -1).all()
    whole = keep[scene.mesh.faces].all(1)  # exactly the faces with three kept vertices, mapped
    np.testing.assert_array_equal(part.faces, index[scene.mesh.faces[whole]])


def test_drop_floaters(scene):
    mesh = scene.mesh
    cleaned = drop_floaters(mesh, 0.01)
    assert cleaned.n_vertices == mesh.n_vertices - 4 and len(cleaned.faces) == len(mesh.faces) - 4
    np.testing.assert_array_equal(cleaned.vertices, np.delete(mesh.vertices, scene.floater, axis=0))
    np.testing.assert_array_equal(cleaned.vertex_colors, np.delete(mesh.vertex_colors, scene.floater, axis=0))
    assert drop_floaters(mesh, 0.0).n_vertices == mesh.n_vertices
    threshold = 4 / (len(mesh.faces) - 4)  # the floater's 4 faces against the largest part's
    assert drop_floaters(mesh, threshold).n_vertices == mesh.n_vertices  # "fewer than": equal is kept
    assert drop_floaters(mesh, np.nextafter(threshold, 1)).n_vertices == mesh.n_vertices - 4
    with pytest.raises(NerfEditError, match=r"in \[0, 1\]"):
        drop_floaters(mesh, 1.5)


def test_largest_component_unchanged(scene):
    """The extraction's default clean-up, now on the shared helpers: the largest part, ties to the lowest face."""
    largest = scene.mesh.largest_component()
    np.testing.assert_array_equal(largest.vertices, np.delete(scene.mesh.vertices, scene.floater, axis=0))
    two = SurfaceMesh(np.eye(3).repeat(2, 0) + [[0, 0, 0], [5, 0, 0]] * 3, [[1, 3, 5], [0, 2, 4]])
    np.testing.assert_array_equal(two.largest_component().vertices, two.vertices[[1, 3, 5]])  # face 0
