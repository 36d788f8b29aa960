"""The editing contract: how the interactive editor (``nerfedit view --mesh MESH --deformer NAME``) edits with a
deformer. A deformer that can be edited names its :class:`EditingBackend` subclass in :attr:`Deformer.editor
<nerfedit_plugin.edit.deformer.Deformer.editor>`; the backend says what the handles grab (its control
:attr:`~EditingBackend.points`), how the handles become the deformer's edit spec (:meth:`~EditingBackend.spec_data`,
read back by :meth:`~EditingBackend.handles_of`), how a pose is previewed (:meth:`~EditingBackend.preview`; during a
drag :meth:`~EditingBackend.preview_drag`, which may show a :class:`LiveView` of a surface of the backend's own
instead of the mesh) and what the viewer draws over the mesh (:meth:`~EditingBackend.lines`).

A handle is an :class:`EditorHandle`: control points held fixed or moved by a similarity ``x ↦ c + s R (x − c) + τ``
about a rest pivot ``c`` — exactly an edit spec's transform at t = 1, and at every t of an animation (the spec's
pivot is written with it). The editor composes every move (drag, turn, scale) into it; the backend decides what the
handle means for its deformer.
"""

from __future__ import annotations

import abc
import dataclasses
import os
from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

import numpy as np

from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.edit.spec import EditSpec, Transform, parse_edit_spec
from nerfedit_plugin.geometry.mesh import SurfaceMesh


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


@dataclasses.dataclass(frozen=True)
class LiveView:
    """What the editor shows while a handle is held, when it is not the mesh itself: a surface of the backend's own,
    ``vertices (N,3)`` float64 over ``faces (F,3)`` int (e.g. the coarse level a large mesh is solved on, as solved),
    and the handle points drawn on it, ``fixed`` and ``moving`` (int64 indices into ``vertices``)."""

    vertices: np.ndarray
    faces: np.ndarray
    fixed: np.ndarray
    moving: np.ndarray


class EditingBackend(abc.ABC):
    """Control points ``points (P,3)`` (rest) the handles index, over ``faces (F,3)`` (picking and geodesic grow;
    None: points only) of ``rest`` edited by the deformer ``config``; ``keys`` its own spec keys (:attr:`own_keys`:
    files as absolute paths, ``auto``, other values as the spec gives them).

    A subclass sets :attr:`points` and :attr:`faces` before calling ``super().__init__`` and implements
    :meth:`preview`; every other member has a default for handles that are spec ``handles`` over the points.
    Refusals are :class:`~nerfedit_plugin.errors.NerfEditError` with a message for the status line.
    """

    what: ClassVar[str] = "vertices"
    """What a handle grabs, for messages."""
    scales: ClassVar[bool] = True
    """Whether a handle may be scaled."""
    own_keys: ClassVar[tuple[str, ...]] = ()
    """The deformer's own spec keys the backend keeps in ``keys`` (files, ``auto`` or values), given on the command
    line (``--cage``, ``--skeleton``) or read from a loaded spec (:meth:`keys_of`)."""
    layer: ClassVar[str | None] = None
    """The viewer layer of :meth:`lines` (None: no overlay)."""

    def __init__(self, rest: SurfaceMesh, config: DeformerConfig, keys: dict) -> None:
        self.rest, self.config, self.keys = rest, config, dict(keys)
        self.posed: np.ndarray = self.points.copy()
        """(P,3): the control points as last previewed."""
        self.last_iterations: int | None = None
        """Solver iterations of the last preview (None: a direct evaluation)."""

    points: np.ndarray
    faces: np.ndarray | None

    @property
    def spec_keys(self) -> frozenset[str]:
        return self.config._target.spec_keys

    @classmethod
    def keys_of(cls, spec: EditSpec) -> dict:
        """The ``keys`` of a loaded ``spec``, to keep editing it: each of :attr:`own_keys` it has, as an absolute
        path (resolved against the spec's folder) or ``auto``."""
        return {
            key: "auto" if spec.extra[key] == "auto" else spec.path(key) for key in cls.own_keys if key in spec.extra
        }

    def check_handle(self, indices: np.ndarray, fixed: bool) -> None:
        """Refuse a handle this backend cannot make; any by default."""
        return None

    def note(self, handles: tuple[EditorHandle, ...]) -> str:
        """A remark on the handles for the status line ("" for none)."""
        return ""

    def handle(self, indices: np.ndarray, fixed: bool) -> EditorHandle:
        """A new handle on ``indices``, pivot at their rest centroid."""
        return EditorHandle(indices, fixed, self.points[indices].mean(0))

    def own_spec(self, folder: Path | None) -> dict:
        """The backend's ``keys`` as the spec writes them: paths relative to ``folder`` (absolute when None)."""
        return {key: _relative(value, folder) for key, value in self.keys.items()}

    def spec_data(self, handles: tuple[EditorHandle, ...], selects: list[dict], folder: Path | None) -> dict:
        """The spec's keys for ``handles`` (handle ``i`` selected by ``selects[i]``) and the backend's own keys
        (:meth:`own_spec`); by default the spec's ``handles``."""
        out = self.own_spec(folder)
        out["handles"] = [
            {"select": select, **({"fixed": True} if h.fixed else {"transform": h.transform_spec()})}
            for h, select in zip(handles, selects)
        ]
        return out

    def handles_of(self, spec: EditSpec) -> tuple[EditorHandle, ...]:
        """The handles of a loaded ``spec`` (by default its ``handles``, selections resolved against the control
        points)."""
        handles = []
        for handle in spec.handles:
            indices = handle.selection.indices(self.points, spec.source, self.faces)
            handles.append(EditorHandle.from_transform(indices, self.points[indices].mean(0), handle.transform))
        return tuple(handles)

    @abc.abstractmethod
    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        """The mesh (V,3) for ``spec`` (parsed from :meth:`spec_data`) at ``frame`` (``deformed``: the last preview,
        a warm start); sets :attr:`posed`."""

    def preview_drag(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray | LiveView:
        """One move of a drag (the handle still held) → what is shown until the next move: the mesh (V,3) as
        :meth:`preview` poses it (the default), or a :class:`LiveView`. After a live view the mesh is posed on
        release: by :meth:`converge`, or, when that returns None, by :meth:`preview`."""
        return self.preview(spec, frame, deformed)

    def converge(
        self, spec: EditSpec, frame: int, deformed: np.ndarray, wanted: Callable[[], bool]
    ) -> tuple[np.ndarray, float, float, int] | None:
        """Finish the preview's solve → ``(vertices, energy before, energy after, iterations)``; None when the
        preview is already exact (the default) or ``wanted()`` turned false between chunks."""
        return None

    def posed_points(self, deformed: np.ndarray) -> np.ndarray:
        """The control points (P,3) as shown with the mesh at ``deformed`` (V,3)."""
        return self.posed

    def lines(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The overlay drawn as lines in the :attr:`layer`: ``(points (N,3), edges (E,2))``, or None."""
        return None


def bind_deformer(config: DeformerConfig, rest: SurfaceMesh, data: dict) -> Deformer:
    """The deformer of ``config`` bound to ``rest`` by the spec ``data`` (file paths absolute, as in ``keys``): a
    backend that re-poses a bound deformer binds it once."""
    model = config.setup()
    model.bind(rest, parse_edit_spec({k: _relative(v, None) for k, v in data.items()}, model.spec_keys, "<editor>"))
    return model


def _relative(value, folder: Path | None):
    """A path value relative to ``folder`` (absolute without one); ``auto`` and other non-files as they are."""
    if not isinstance(value, Path):
        return value
    return str(value if folder is None else Path(os.path.relpath(value, folder)))
