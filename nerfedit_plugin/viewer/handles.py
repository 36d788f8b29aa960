"""An editor handle: control points (mesh or cage vertices, or one skeleton joint) held fixed or moved by a similarity
``x ↦ c + s R (x − c) + τ`` about a rest pivot ``c`` — exactly an edit spec's transform at t = 1, and at every t of an
animation (the spec's pivot is written with it)."""

from __future__ import annotations

import dataclasses

import numpy as np

from nerfedit_plugin.edit.spec import Transform


@dataclasses.dataclass(frozen=True)
class EditorHandle:
    """A handle: control point ``indices`` (sorted, unique), ``fixed`` or moved by ``translate`` τ (3,), ``rotvec``
    (3,, radians) and ``scale`` s about ``center`` c (the rest pivot: its selection's rest centroid, a joint's head, or
    the ``rotate.center`` of a loaded spec)."""

    indices: np.ndarray
    fixed: bool
    center: np.ndarray
    translate: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    rotvec: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    @classmethod
    def from_transform(cls, indices: np.ndarray, centroid: np.ndarray, transform: Transform | None) -> EditorHandle:
        """The handle of a spec's handle over ``indices`` (rest ``centroid``; ``transform`` None: fixed)."""
        if transform is None:
            return cls(indices, True, centroid)
        center = centroid if transform.center is None else transform.center
        return cls(indices, False, center, transform.translate, transform.rotvec, float(transform.scale))

    @property
    def pivot(self) -> np.ndarray:
        """Where the rest pivot is now (``c + τ``): the default pivot of a rotation or scale."""
        return self.center + self.translate

    @property
    def rotate_spec(self) -> dict:
        """``{"axis", "degrees"}`` of the rotation (axis z for none)."""
        angle = float(np.linalg.norm(self.rotvec))
        axis = self.rotvec / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
        return {"axis": [float(v) for v in axis], "degrees": float(np.degrees(angle))}

    def transform_spec(self) -> dict:
        """The spec's ``transform`` mapping (plain floats; ``rotate``, with the pivot as its ``center``, only when
        turned or scaled; ``scale`` only when not 1)."""
        out: dict = {"translate": [float(v) for v in self.translate]}
        if np.any(self.rotvec) or self.scale != 1.0:
            out["rotate"] = {**self.rotate_spec, "center": [float(v) for v in self.center]}
        if self.scale != 1.0:
            out["scale"] = float(self.scale)
        return out
