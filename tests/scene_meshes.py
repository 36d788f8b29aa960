"""A generated scene mesh for the clean-up and object-selection tests: a floor grid with two open boxes standing on it
(their bottom rims are floor vertices, so floor and boxes are one connected part, as in an extracted scene) and a
tiny floating tetrahedron."""

from dataclasses import dataclass

import numpy as np

from nerfedit_plugin.geometry.mesh import SurfaceMesh

SPACING = 0.1
SIDE = 21
"""Floor: SIDE × SIDE vertices on z = 0, SPACING apart, centred on the origin."""
BOXES = (((2, 6), (3, 8), 0.4), ((12, 17), (11, 15), 0.25))
"""Each box: its footprint's floor-grid index ranges (i, j) and its height."""
FLOATER = (np.array([0.7, -0.7, 0.6]), 0.03)
"""The floater's corner and size."""


@dataclass
class Scene:
    mesh: SurfaceMesh
    floor: np.ndarray
    """Indices of the floor's vertices (z = 0, rims included)."""
    boxes: tuple[np.ndarray, ...]
    """Indices of each box's vertices above the floor."""
    floater: np.ndarray
    """Indices of the floater's vertices."""


def _grid_faces(ids: np.ndarray) -> np.ndarray:
    """ids (n, m) vertex grid → its 2 (n−1)(m−1) triangles."""
    a, b, c, d = ids[:-1, :-1], ids[1:, :-1], ids[1:, 1:], ids[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def _ring(i: tuple[int, int], j: tuple[int, int]) -> list[tuple[int, int]]:
    """Grid cells (i, j) around the footprint's boundary, in loop order."""
    (i0, i1), (j0, j1) = i, j
    return (
        [(a, j0) for a in range(i0, i1)]
        + [(i1, b) for b in range(j0, j1)]
        + [(a, j1) for a in range(i1, i0, -1)]
        + [(i0, b) for b in range(j1, j0, -1)]
    )


def floor_scene() -> Scene:
    """The scene: floor, boxes and floater, with vertex colours (grey floor, red and green boxes, blue floater)."""
    coords = (np.arange(SIDE) - SIDE // 2) * SPACING
    gx, gy = np.meshgrid(coords, coords, indexing="ij")
    vertices = [np.stack([gx, gy, np.zeros_like(gx)], -1).reshape(-1, 3)]
    colors = [np.full((SIDE * SIDE, 3), 0.5)]
    floor_ids = np.arange(SIDE * SIDE).reshape(SIDE, SIDE)
    faces = [_grid_faces(floor_ids)]
    n = SIDE * SIDE
    boxes = []
    for (i, j, height), color in zip(BOXES, ([1, 0, 0], [0, 1, 0]), strict=True):
        ring = _ring(i, j)
        top = np.arange(n, n + (i[1] - i[0] + 1) * (j[1] - j[0] + 1)).reshape(i[1] - i[0] + 1, j[1] - j[0] + 1)
        top_xyz = np.stack([gx, gy, np.full_like(gx, height)], -1)[i[0] : i[1] + 1, j[0] : j[1] + 1].reshape(-1, 3)
        middle = np.arange(top.max() + 1, top.max() + 1 + len(ring))
        middle_xyz = np.array([[coords[a], coords[b], height / 2] for a, b in ring])
        rows = [
            np.array([floor_ids[a, b] for a, b in ring]),
            middle,
            np.array([top[a - i[0], b - j[0]] for a, b in ring]),
        ]
        walls = np.stack([np.stack([r, np.roll(r, -1)], -1) for r in rows], 1)  # (ring, 3 rows, 2)
        faces += [_grid_faces(walls[k]) for k in range(len(ring))]
        faces.append(_grid_faces(top))
        vertices += [top_xyz, middle_xyz]
        colors += [np.tile(color, (len(top_xyz) + len(middle_xyz), 1))]
        boxes.append(np.arange(n, middle.max() + 1))
        n = middle.max() + 1
    corner, size = FLOATER
    vertices.append(corner + size * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]))
    colors.append(np.tile([0.0, 0.0, 1.0], (4, 1)))
    faces.append(n + np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    mesh = SurfaceMesh(np.concatenate(vertices), np.concatenate(faces), np.concatenate(colors))
    return Scene(mesh, floor_ids.reshape(-1), tuple(boxes), np.arange(n, n + 4))
