"""Tet-mesh utilities: signed volumes, orientation, boundary, cleaning, distance to the boundary, Kuhn grids."""

from __future__ import annotations

import itertools

import numpy as np

DEGENERATE_VOLUME_RATIO = 1e-8
"""Tets with volume <= this x the median tet volume count as zero-volume and are dropped by :func:`clean_tets`."""


def tet_signed_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """vertices (N,3) float64, tets (K,4) int → (K,) float64 signed volumes ``((b−a) × (c−a)) · (d−a) / 6``;
    positive = positively oriented."""
    a, b, c, d = (vertices[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def orient_tets(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """vertices (N,3) float64, tets (K,4) int → (K,4) int64 copy of ``tets`` with corners 1 and 2 of every
    negatively oriented tet swapped (zero-volume tets stay as they are)."""
    tets = np.asarray(tets, dtype=np.int64).copy()
    negative = tet_signed_volumes(vertices, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return tets


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """tets (K,4) int → (B,3) the triangles that belong to exactly one tet, oriented outward for positively
    oriented tets."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def clean_tets(vertices: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """vertices (N,3) float, tets (K,4) int → ``(vertices (N',3) float64, tets (K',4) int64, n_dropped)``: tets
    oriented positively (:func:`orient_tets`), zero-volume ones (<= :data:`DEGENERATE_VOLUME_RATIO` x the median
    volume) dropped, unreferenced vertices dropped (order kept)."""
    tets = orient_tets(vertices, tets)
    magnitude = np.abs(tet_signed_volumes(vertices, tets))
    keep = magnitude > DEGENERATE_VOLUME_RATIO * np.median(magnitude) if len(tets) else magnitude > 0
    tets = tets[keep]
    used, tets = np.unique(tets, return_inverse=True)
    return np.ascontiguousarray(vertices[used], dtype=np.float64), tets.reshape(-1, 4), int((~keep).sum())


def distance_to_boundary(vertices: np.ndarray, tets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """vertices (N,3) float, tets (K,4) int, points (M,3) float → (M,) float64 unsigned distance to the boundary
    surface of the tet mesh (Open3D, computed in float32)."""
    from nerfedit_plugin.geometry.raycast import distance, raycasting_scene

    return distance(raycasting_scene(vertices, boundary_faces(tets)), points).astype(np.float64)


def kuhn_grid(cells, low=0.0, high=1.0) -> tuple[np.ndarray, np.ndarray]:
    """The box ``[low, high]`` cut into ``cells`` equal boxes per axis, each into the 6 Kuhn tets around its main
    diagonal: a conforming tet mesh.

    cells int or (3,) int, low and high float or (3,) float → vertices ((c₀+1)(c₁+1)(c₂+1), 3) float64
    ``low + (high − low) · (i, j, k) / cells`` at index ``(i (c₁+1) + j)(c₂+1) + k``, and tets (6 c₀c₁c₂, 4) int64:
    one block of c₀c₁c₂ per axis order (in ``itertools.permutations`` order), each tet the path from a box's low
    corner to its high corner one axis step at a time. Tets of odd axis orders are negatively oriented (as built;
    :func:`orient_tets` makes all positive)."""
    cells = np.broadcast_to(np.asarray(cells, dtype=np.int64), (3,))
    low, high = (np.broadcast_to(np.asarray(bound, dtype=np.float64), (3,)) for bound in (low, high))
    lattice = np.stack(np.meshgrid(*(np.arange(c + 1) for c in cells), indexing="ij"), -1).reshape(-1, 3)
    vertices = low + (high - low) * (lattice / cells)
    index = np.arange(len(lattice)).reshape(tuple(cells + 1))
    corner = np.stack(np.meshgrid(*(np.arange(c) for c in cells), indexing="ij"), -1).reshape(-1, 3)
    tets = []
    for order in itertools.permutations(range(3)):
        path = [corner]
        for axis in order:
            step = path[-1].copy()
            step[:, axis] += 1
            path.append(step)
        tets.append(np.stack([index[p[:, 0], p[:, 1], p[:, 2]] for p in path], 1))
    return vertices, np.concatenate(tets)
