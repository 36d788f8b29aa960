"""Selection files: vertices picked on a mesh (by the viewer, a script, a user), saved so an edit spec can name them
(``{"select": {"file": "ears.selection.json"}}``).

Format (JSON): ``{"format": "nerfedit.selection", "version": 1, "vertices": V, "sha256": …, "indices": [i, …],
"points": [[x, y, z], …], "clearance": [c, …]}`` — the picked vertex indices of a mesh of ``V`` vertices whose
positions (float64, row-major bytes) hash to ``sha256``, the picked vertices' positions, and each one's distance to
the nearest vertex not picked. Resolved against rest points (:meth:`SelectionFile.resolve`): the same points (count
and hash) take the indices as they are; any others — the mesh re-extracted from the field, moved into another
frame, the tet proxy's vertices for ``tet-edit`` — take the points whose nearest picked position lies within half
its clearance (a fallback by position: exact for the same vertices moved rigidly, since every unpicked vertex is a
full clearance away; on another mesh, the picked part, its border within half the gap to the unpicked).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import write_text

FORMAT, VERSION = "nerfedit.selection", 1
NEAREST = 8
"""Stored points a rest point is tested against in the fallback by position (its nearest ones)."""


def points_hash(points: np.ndarray) -> str:
    """points (V,3) → sha256 hex digest of their float64 row-major bytes."""
    return hashlib.sha256(np.ascontiguousarray(points, dtype=np.float64).tobytes()).hexdigest()


@dataclass(frozen=True)
class SelectionFile:
    """A read selection file: ``indices (S,) int64``, ``points (S,3) float64``, ``clearance (S,) float64``, the
    indexed mesh's ``n_vertices`` and ``sha256``, ``path``."""

    indices: np.ndarray
    points: np.ndarray
    clearance: np.ndarray
    n_vertices: int
    sha256: str
    path: Path

    def resolve(self, points: np.ndarray, placed: np.ndarray | None = None) -> np.ndarray:
        """rest points (V,3) → sorted indices selected among them: ``indices`` when ``points`` are the indexed mesh's
        vertices (same count and hash), else those within half its clearance of one of their :data:`NEAREST` nearest
        stored points (ties included), compared as ``placed`` (V,3) (the points in the file's frame; default
        ``points``)."""
        if len(points) == self.n_vertices and points_hash(points) == self.sha256:
            return self.indices
        k = min(NEAREST, len(self.points))
        distance, nearest = cKDTree(self.points).query(points if placed is None else placed, k=k)
        distance, nearest = distance.reshape(len(distance), k), nearest.reshape(len(nearest), k)
        return np.flatnonzero((distance <= 0.5 * self.clearance[nearest]).any(axis=1))


def write_selection(path: str | os.PathLike, mesh: SurfaceMesh, indices: np.ndarray) -> Path:
    """Write the selection of ``indices`` (int, in range, non-empty) of ``mesh`` to ``path`` (atomically) → path."""
    indices = np.unique(np.asarray(indices, dtype=np.int64))
    if not len(indices) or indices[0] < 0 or indices[-1] >= mesh.n_vertices:
        raise NerfEditError(f"{path}: a selection needs vertex indices in [0, {mesh.n_vertices}), got {len(indices)}")
    others = np.setdiff1d(np.arange(mesh.n_vertices), indices)
    picked = mesh.vertices[indices]
    clearance = cKDTree(mesh.vertices[others]).query(picked)[0] if len(others) else np.full(len(indices), np.inf)
    record = {
        "format": FORMAT,
        "version": VERSION,
        "vertices": mesh.n_vertices,
        "sha256": points_hash(mesh.vertices),
        "indices": indices.tolist(),
        "points": picked.tolist(),
        "clearance": np.minimum(clearance, mesh.bbox_diagonal).tolist(),
    }
    write_text(path, json.dumps(record))
    return Path(path)


def read_selection(path: str | os.PathLike, where: str) -> SelectionFile:
    """Read a selection file; a missing, foreign or malformed one is a :class:`NerfEditError` naming ``where`` (the
    spec key) and the file."""
    path = Path(path)

    def bad(problem: str) -> NerfEditError:
        return NerfEditError(f"{where}: {path}: {problem}")

    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise bad("selection file not found") from None
    except (OSError, ValueError) as exc:
        raise bad(f"cannot read ({exc})") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT or record.get("version") != VERSION:
        raise bad(f"not a {FORMAT} file of version {VERSION}")
    try:
        indices = np.asarray(record["indices"], dtype=np.int64)
        points = np.asarray(record["points"], dtype=np.float64)
        clearance = np.asarray(record["clearance"], dtype=np.float64)
        n_vertices, sha256 = int(record["vertices"]), str(record["sha256"])
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise bad(f"malformed ({type(exc).__name__}: {exc})") from None
    shapes = (
        indices.ndim == 1 and len(indices) and points.shape == (len(indices), 3) and clearance.shape == indices.shape
    )
    if not (shapes and np.isfinite(points).all() and np.isfinite(clearance).all() and (clearance >= 0).all()):
        raise bad("malformed (indices, points and clearance disagree)")
    if indices.min() < 0 or indices.max() >= n_vertices:
        raise bad(f"malformed (an index outside the mesh's {n_vertices} vertices)")
    return SelectionFile(indices, points, clearance, n_vertices, sha256, path)
