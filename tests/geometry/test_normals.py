"""Compiled face normals against numpy's cross product."""

import numpy as np

from nerfedit_plugin.geometry.normals import face_normals
from tests.geometry.test_arap import sample_mesh


def test_face_normals_are_the_cross_products():
    vertices, faces = sample_mesh("cow.obj")
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    expected = np.cross(b - a, c - a)
    assert np.abs(face_normals(vertices, faces) - expected).max() <= 1e-15 * np.abs(expected).max()
    assert face_normals(vertices, faces[:0]).shape == (0, 3)
