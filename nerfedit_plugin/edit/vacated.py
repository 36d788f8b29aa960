"""Filling the floor an object leaves: a patch of the surrounding floor copied over its footprint (scene edits).

Where an object stood, the floor was never observed: a trained field holds there whatever fitted the views (often
the object's underside or a dark blur). ``vacated: fill`` covers that footprint with a neighbouring piece of floor:
a thin slab ``|height| ≤ h`` around the floor plane (the scene mesh's largest plane,
:func:`~nerfedit_plugin.geometry.cleanup.largest_plane`) over the box of the footprint, mapped by a translation along
the floor onto the same slab beside the footprint — one of the four sides, the one whose column holds the fewest
vertices off the floor (the freest floor). It is one more instance of the scene deformation that reads its region and
vacates nothing, listed after every object: moved objects still show where they are, and the vacated space above
the slab stays empty.
"""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.geometry.cleanup import largest_plane
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets

THICKNESS = 0.04
"""Half-height ``h`` of the slab, as a fraction of the object's bounding-box diagonal (a floor's band in a field)."""
MARGIN = 0.05
"""The footprint's box grows by this fraction of the object's bounding-box diagonal on every side."""
CELLS = 8
"""Tets of the slab: CELLS × CELLS × 1 boxes, 6 tets each."""


def fill_patch(scene: SurfaceMesh, footprint: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``scene`` (the rest mesh), ``footprint (P,3)`` (the points the object vacates: its own region at rest),
    ``size`` (the object's bounding-box diagonal) → the patch as ``(rest (N,3), tets (K,4), deformed (N,3))``:
    ``deformed`` the slab over the footprint, ``rest`` the same slab moved beside it (module docstring)."""
    plane, on = largest_plane(scene)
    normal = plane[:3]
    tangent = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2].T  # two unit vectors in the plane
    uv = footprint @ tangent.T
    margin, half = MARGIN * size, THICKNESS * size
    low, high = uv.min(0) - margin, uv.max(0) + margin
    grid, tets = kuhn_grid((CELLS, CELLS, 1), (*low, -half), (*high, half))
    origin = -plane[3] * normal  # the plane's point nearest the origin
    slab = origin + grid[:, :2] @ tangent + grid[:, 2:] * normal
    tets = orient_tets(slab, tets)
    width = high - low
    shifts = [sign * width[axis] * tangent[axis] for axis in (0, 1) for sign in (1.0, -1.0)]
    off = scene.vertices[~on]
    off_uv, off_height = off @ tangent.T, off @ normal + plane[3]

    def crowd(shift: np.ndarray) -> int:
        lo, hi = low + shift @ tangent.T, high + shift @ tangent.T
        return int(np.count_nonzero(np.all((off_uv >= lo) & (off_uv <= hi), 1) & (off_height > -half)))

    shift = min(shifts, key=crowd)
    return slab + shift, tets, slab
