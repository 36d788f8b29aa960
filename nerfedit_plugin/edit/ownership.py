"""The part of an object's tet proxy that holds the object's own geometry (scene edits).

A point is the object's when it lies inside the object's surface, or outside it but nearer to it than to the rest
of the mesh (the unselected geometry: a floor, a wall, other objects) by more than :data:`TIE` × the object's size:
an object standing on a floor owns its inside down to its base, the floor owns the slab under it. A tet is the
object's when its centroid is. Tets near a surface whose corners and centroid disagree (an object standing on a
floor: the proxy's margin reaches into it) are bisected (:func:`~nerfedit_plugin.geometry.refine.bisect`)
:data:`ROUNDS` times, so the boundary is followed to within 2^-ROUNDS of the tet size; the deformed frames are carried
onto the refined tets exactly (:meth:`~nerfedit_plugin.geometry.refine.Refinement.prolong`: the map is piecewise
linear). What the object's instances carry, and what its original leaves empty when it moves, is this region only.
"""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.refine import bisect

ROUNDS = 1
"""Bisections of the tets the ownership boundary crosses near a surface (each multiplies their count by ~8; on the
tests' box on a floor, 1 round: 11.7k → 15.9k tets, 3 rounds: 102k)."""
TIE = 1e-6
"""Distances closer than this fraction of the object's bounding-box diagonal count as equal (coincident faces)."""


def own_region(
    vertices: np.ndarray, tets: np.ndarray, frames: np.ndarray, surface: SurfaceMesh, others: SurfaceMesh
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A proxy ``vertices (N,3)``, ``tets (K,4)`` with deformed ``frames (F,N,3)`` of the object ``surface`` among
    ``others`` → ``(rest (N',3), tets (K',4), frames (F,N',3))``: its own tets (module docstring), over only the
    vertices they use. Without other geometry every tet is the object's."""
    frames = np.asarray(frames, dtype=np.float64)
    if len(others.faces) == 0:
        return np.asarray(vertices, dtype=np.float64), np.asarray(tets, dtype=np.int64), frames
    mine = raycast.raycasting_scene(surface.vertices, surface.faces)
    theirs = raycast.raycasting_scene(others.vertices, others.faces)

    tie = TIE * surface.bbox_diagonal

    def owned(points: np.ndarray) -> np.ndarray:
        nearer = raycast.distance(mine, points) < raycast.distance(theirs, points) - tie
        return nearer | raycast.occupancy(mine, points, nsamples=3)

    for _ in range(ROUNDS):
        corners = owned(vertices)[tets]
        centroids = vertices[tets].mean(1)
        size = np.linalg.norm(vertices[tets] - centroids[:, None], axis=-1).max(1)
        near = np.minimum(raycast.distance(mine, centroids), raycast.distance(theirs, centroids)) < size
        mixed = (corners != owned(centroids)[:, None]).any(1) & near
        if not mixed.any():
            break
        refinement = bisect(vertices, tets, mixed)
        vertices, tets = refinement.vertices, refinement.tets
        frames = np.stack([refinement.prolong(f) for f in frames])
    keep = owned(vertices[tets].mean(1))
    used = np.unique(tets[keep])
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[tets[keep]], frames[:, used]
