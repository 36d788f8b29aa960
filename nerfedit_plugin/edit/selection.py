"""Handle selections of edit specs (docs/architecture.md, "Edit spec"): which rest points a handle grabs.

Kinds: ``box`` (min/max corners), ``sphere`` (center/radius), ``indices``, a selection ``file``
(:mod:`~nerfedit_plugin.edit.selection_file`) and ``component``, the connected part of the rest mesh nearest a
point, optionally after dropping the floor (:func:`~nerfedit_plugin.geometry.cleanup.largest_plane`).
:func:`parse_selection` validates a spec's ``select`` entry; :meth:`Selection.indices` resolves it against rest
points (and the rest mesh's faces, which ``component`` needs).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nerfedit_plugin.edit.selection_file import read_selection
from nerfedit_plugin.edit.spec_values import check_keys, number, resolve_path, spec_error, vector
from nerfedit_plugin.geometry.cleanup import largest_plane
from nerfedit_plugin.geometry.mesh import SurfaceMesh

SELECT_KINDS = ("box", "sphere", "indices", "file", "component")
COMPONENT_KEYS = ("near", "drop_plane", "plane_distance", "max_distance", "min_faces")
NEAR_FRACTION = 0.05
"""Default ``component.max_distance``: this fraction of the rest points' bounding-box diagonal (in the spec's
frame)."""


@dataclass(frozen=True)
class Selection:
    """Which rest points a handle grabs: ``kind`` (one of :data:`SELECT_KINDS`), its validated ``params``, its spec
    ``key`` (``handles[0].select.box``) and ``to_spec`` (4,4) float64 or None: the similarity taking rest points into
    the frame the selection's positions are given in (set by :meth:`EditSpec.in_world`; ``indices`` ignore it)."""

    kind: str
    params: dict
    key: str
    to_spec: np.ndarray | None = None

    def indices(self, points: np.ndarray, source: str, faces: np.ndarray | None = None) -> np.ndarray:
        """Sorted indices of the selected ``points`` (V,3) (``source``: the spec file, for errors); ``faces``
        (F,3) int, the rest mesh's triangles over ``points``, are needed by ``component`` only (without them it is an
        error). An empty or out-of-range selection is an error."""
        placed = points
        if self.to_spec is not None and self.kind != "indices":
            placed = points @ self.to_spec[:3, :3].T + self.to_spec[:3, 3]
        if self.kind == "file":
            idx = self.params["file"].resolve(points, placed)
        elif self.kind == "box":
            inside = np.all((placed >= self.params["min"]) & (placed <= self.params["max"]), axis=1)
            idx = np.flatnonzero(inside)
        elif self.kind == "sphere":
            dist = np.linalg.norm(placed - self.params["center"], axis=1)
            idx = np.flatnonzero(dist <= self.params["radius"])
        elif self.kind == "component":
            if faces is None:
                raise spec_error(source, self.key, "needs the rest mesh's faces, and this step gives points only")
            idx = self._component(SurfaceMesh(placed, faces), source)
        else:
            idx = self.params["indices"]
            if idx.size and (idx.min() < 0 or idx.max() >= len(points)):
                bad = idx[(idx < 0) | (idx >= len(points))][0]
                raise spec_error(source, self.key, f"index {bad} out of range for {len(points)} points")
        if idx.size == 0:
            raise spec_error(source, self.key, f"selects no points (of {len(points)})")
        return idx

    def _component(self, mesh: SurfaceMesh, source: str) -> np.ndarray:
        """The vertices of ``mesh`` (in the spec's frame) in the part of the vertex nearest ``near`` among the plane's
        (when dropped) and those of parts of at least ``min_faces`` faces."""
        p, key = self.params, f"{self.key}.near"
        on_plane = np.zeros(mesh.n_vertices, dtype=bool)
        if p["drop_plane"]:
            on_plane = largest_plane(mesh, p["plane_distance"])[1]
        part = mesh.submesh(~on_plane)[0]
        part_labels = part.component_labels()
        sizes = np.bincount(part_labels[part.faces[:, 0]], minlength=part.n_vertices)  # faces of each part
        labels, big = np.full(mesh.n_vertices, -1), np.zeros(mesh.n_vertices, dtype=bool)
        labels[~on_plane], big[~on_plane] = part_labels, sizes[part_labels] >= p["min_faces"]
        candidates = np.flatnonzero(on_plane | big)
        if not candidates.size:
            raise spec_error(source, key, f"the mesh has no part of {p['min_faces']} faces or more")
        distance = np.linalg.norm(mesh.vertices[candidates] - p["near"], axis=1)
        nearest = candidates[distance.argmin()]
        limit = NEAR_FRACTION * mesh.bbox_diagonal if p["max_distance"] is None else p["max_distance"]
        if distance.min() > limit:
            raise spec_error(
                source, key, f"the nearest vertex is {distance.min():.4g} away, more than max_distance {limit:.4g}"
            )
        if on_plane[nearest]:
            raise spec_error(source, key, "the nearest vertex lies on the dropped plane (the floor): aim at the object")
        return np.flatnonzero(labels == labels[nearest])


def parse_selection(obj: Any, source: str, key: str, base_dir: Path) -> Selection:
    """Validate a handle's ``select`` mapping (one kind of :data:`SELECT_KINDS`; ``key`` its dotted path, a ``file``
    relative to ``base_dir``) → :class:`Selection`, else the :class:`NerfEditError` naming ``source`` and the key."""
    check_keys(obj, SELECT_KINDS, source, key)
    if len(obj) != 1:
        raise spec_error(source, key, f"expected exactly one of {list(SELECT_KINDS)}")
    kind, value = next(iter(obj.items()))
    key = f"{key}.{kind}"
    if kind == "box":
        check_keys(value, ("min", "max"), source, key, required=("min", "max"))
        lo, hi = vector(value["min"], source, f"{key}.min"), vector(value["max"], source, f"{key}.max")
        if np.any(lo > hi):
            raise spec_error(source, key, "min exceeds max")
        return Selection(kind, {"min": lo, "max": hi}, key)
    if kind == "file":
        if not isinstance(value, (str, os.PathLike)):
            raise spec_error(source, key, f"expected a selection file path, got {value!r}")
        where = f"{source}: {key}"
        selection = read_selection(resolve_path(base_dir, value, source, key), where)
        return Selection(kind, {"file": selection}, key)
    if kind == "sphere":
        check_keys(value, ("center", "radius"), source, key, required=("center", "radius"))
        center = vector(value["center"], source, f"{key}.center")
        return Selection(
            kind, {"center": center, "radius": number(value["radius"], source, f"{key}.radius", True)}, key
        )
    if kind == "component":
        return Selection(kind, _parse_component(value, source, key), key)
    if not isinstance(value, list) or not value or not set(map(type, value)) <= {int}:
        raise spec_error(source, key, "expected a non-empty list of integer vertex indices")
    big = next((i for i in (min(value), max(value)) if not -(2**63) <= i < 2**63), None)
    if big is not None:
        raise spec_error(source, key, f"index {big} out of range")
    indices = np.asarray(value, dtype=np.int64)
    if not np.all(indices[1:] > indices[:-1]):  # a sorted list of distinct indices (the editor's) is kept as it is
        indices = np.unique(indices)
    return Selection(kind, {"indices": indices}, key)


def _parse_component(value: Any, source: str, key: str) -> dict:
    """``{"near": [x, y, z], "drop_plane": bool, "plane_distance": d, "max_distance": d, "min_faces": n}`` (all but
    ``near`` optional; ``plane_distance`` only with ``drop_plane``) → the params of a ``component`` selection."""
    check_keys(value, COMPONENT_KEYS, source, key, required=("near",))
    drop_plane = value.get("drop_plane", False)
    if not isinstance(drop_plane, bool):
        raise spec_error(source, f"{key}.drop_plane", f"expected true or false, got {drop_plane!r}")
    if "plane_distance" in value and not drop_plane:
        raise spec_error(source, f"{key}.plane_distance", "applies only with drop_plane: true")
    min_faces = value.get("min_faces", 1)
    if isinstance(min_faces, bool) or not isinstance(min_faces, int) or min_faces < 1:
        raise spec_error(source, f"{key}.min_faces", f"expected an integer >= 1, got {min_faces!r}")

    def distance(name: str) -> float | None:
        return number(value[name], source, f"{key}.{name}", positive=True) if name in value else None

    return {
        "near": vector(value["near"], source, f"{key}.near"),
        "drop_plane": drop_plane,
        "plane_distance": distance("plane_distance"),
        "max_distance": distance("max_distance"),
        "min_faces": min_faces,
    }
