"""Twist deformer: rotate each point about an axis by an angle proportional to its height along that axis.

Edit spec: ``{"twist": {"axis": [0, 0, 1], "degrees": 90, "center": [x, y, z]}, "frames": n}``; the lowest rest
point (along ``axis``) stays, the highest turns by ``degrees``; ``center`` (a point on the axis) defaults to the
rest bounding-box centre. Editable in the viewer (``nerfedit view --mesh MESH --deformer twist``): one handle on the
axis whose turn about it sets ``degrees`` (:class:`TwistBackend`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import tyro
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.edit.editing import EditingBackend, EditorHandle, bind_deformer
from nerfedit_plugin.errors import NerfEditError


@dataclasses.dataclass
class TwistConfig(DeformerConfig):
    """Twist about an axis."""

    _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: TwistDeformer)
    anchor: float = 0.0
    """Height (0 = lowest rest point, 1 = highest) that does not turn."""


def _numbers(value, n, where):
    arr = np.asarray(value, dtype=np.float64) if isinstance(value, list) else np.full(n + 1, np.nan)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise NerfEditError(f"{where}: expected {n} finite number(s), got {value!r}")
    return arr


class TwistBackend(EditingBackend):
    """The viewer's handle: one point on the axis, level with the highest rest point; its turn about the axis (the
    component of its rotation vector along it) is the twist's ``degrees``. ``keys["twist"]``: the ``axis`` and
    ``center`` kept (default: the longest side of the rest bounding box, through its centre)."""

    what, scales, own_keys, layer = "twist handles", False, ("twist",), "twist"

    def __init__(self, rest, config, keys):
        twist = {"axis": np.eye(3)[np.argmax(np.ptp(rest.vertices, axis=0))].tolist(), **keys.get("twist", {})}
        self.model = m = bind_deformer(config, rest, {"twist": {**twist, "degrees": 0}})
        self.ends = m.center + np.outer([m.low, m.low + m.span], m.axis)  # the axis, lowest to highest rest point
        self.points, self.faces = self.ends[1:], None
        super().__init__(rest, config, {"twist": {"axis": m.axis.tolist(), "center": m.center.tolist()}})

    @classmethod
    def keys_of(cls, spec):
        twist = spec.extra.get("twist")
        return {"twist": {k: twist[k] for k in ("axis", "center") if k in twist}} if isinstance(twist, dict) else {}

    def check_handle(self, indices, fixed):
        if fixed:
            raise NerfEditError("mark: the twist handle turns (the anchor height stays by itself); mark it moving")

    def note(self, handles):
        moved = any(np.any(h.translate) for h in handles)
        return "; the twist takes the handle's turn about its axis, not its move" if moved else ""

    def spec_data(self, handles, selects, folder):
        degrees = sum(math.degrees(h.rotvec @ self.model.axis) for h in handles)
        return {"twist": {**self.keys["twist"], "degrees": degrees}}

    def handles_of(self, spec):
        self.model.bind(self.rest, spec)
        return (EditorHandle(np.array([0]), False, self.points[0], rotvec=self.model.radians * self.model.axis),)

    def preview(self, spec, frame, deformed):
        self.model.bind(self.rest, spec)
        return self.model.deform_points(self.rest.vertices, frame)

    def lines(self):
        return self.ends, np.array([[0, 1]])


class TwistDeformer(Deformer):
    spec_keys = frozenset({"twist"})
    editor = TwistBackend

    def bind(self, rest, edit):
        where = f"{edit.source}: twist"
        spec = edit.extra.get("twist")
        if not isinstance(spec, dict) or not {"axis", "degrees"} <= set(spec) <= {"axis", "degrees", "center"}:
            raise NerfEditError(f"{where}: expected a mapping with axis, degrees and optionally center")
        axis = _numbers(spec["axis"], 3, f"{where}.axis")
        if not np.linalg.norm(axis):
            raise NerfEditError(f"{where}.axis: is the zero vector")
        self.axis = axis / np.linalg.norm(axis)
        self.radians = math.radians(_numbers([spec["degrees"]], 1, f"{where}.degrees")[0])
        box = rest.vertices.min(0), rest.vertices.max(0)
        self.center = _numbers(spec["center"], 3, f"{where}.center") if "center" in spec else (box[0] + box[1]) / 2
        height = (rest.vertices - self.center) @ self.axis
        self.low, self.span = height.min(), max(np.ptp(height), 1e-12)
        self.rest, self.times = rest.vertices.copy(), edit.times

    def deform_points(self, points, frame):
        points = np.asarray(points, dtype=np.float64)
        fraction = ((points - self.center) @ self.axis - self.low) / self.span - self.config.anchor
        turns = Rotation.from_rotvec(np.outer(self.times[frame] * self.radians * fraction, self.axis))
        return self.center + turns.apply(points - self.center)

    def deform(self):
        return np.stack([self.deform_points(self.rest, f) for f in range(len(self.times))])

    @classmethod
    def placed_edit(cls, edit, scale, offset, base_dir, folder):
        """Conformance-kit hook: the twist's centre is a point and moves with the mesh; axis and angle stay."""
        twist = dict(edit["twist"])
        if "center" in twist:
            twist["center"] = (scale * np.asarray(twist["center"], dtype=np.float64) + offset).tolist()
        return {**edit, "twist": twist}
