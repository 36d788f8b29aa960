"""Editing backends: what the editor's handles grab and how a pose is previewed, one per deformer (chosen by its
registry name, :func:`editing_backend`).

- ``arap``: handles on mesh vertices; the preview re-solves the surface ARAP with a solver prefactored for the
  handle vertices, warm-started, a few iterations; :meth:`ArapBackend.converge` finishes that solve (settle on release).
- ``cage``: handles on the cage's vertices (``"cage": "auto"`` or a cage file); the deformer is bound once (the cage
  and the coordinates of every mesh vertex) and each preview re-poses it through its public ``deformed_cages``.
- ``skeleton``: a handle is one joint, turned (and moved) about its head; the deformer is bound once (the skinning
  weights) and each preview re-poses it through its public ``rot`` / ``trans`` (forward kinematics of the pose).

Each backend writes its deformer's own spec keys (paths relative to the spec's folder) and reads them back
(:meth:`EditingBackend.handles_of`), so a saved spec opens again for more editing.
"""

from __future__ import annotations

import abc
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.edit.spec import EditSpec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.arap import ArapSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.viewer.handles import EditorHandle

PREVIEW_ITERATIONS = 2
"""ARAP local/global iterations per preview solve (each ~30–40 ms on the 28k-vertex bunny, 2 cores), plain: over two
iterations Anderson acceleration's extra local steps cost more than they gain (bunny drag: 81 vs 152 ms per move,
+53 % vs +42 % energy above the converged solve; docs/benchmarks.md)."""
CONVERGE_CHUNK = 5
"""ARAP iterations between two checks that a settle-on-release is still wanted. The settle uses Anderson, not the
deformer's L-BFGS: restarted every 5 iterations, L-BFGS loses its history (bunny head edit: 66 iterations vs
Anderson's 56 to the stopping test)."""


class EditingBackend(abc.ABC):
    """Control points ``points (P,3)`` (rest) the handles index, over ``faces (F,3)`` (picking and geodesic grow;
    None: points only) of ``rest`` edited by the deformer ``config``; ``keys`` its own spec keys (absolute paths)."""

    what: ClassVar[str] = "vertices"
    """What a handle grabs, for messages."""
    scales: ClassVar[bool] = True
    """Whether a handle may be scaled."""
    file_keys: ClassVar[tuple[str, ...]] = ()
    """The deformer's own spec keys the backend keeps (files, or ``auto``)."""
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

    def check_handle(self, indices: np.ndarray, fixed: bool) -> None:
        """Refuse a handle this backend cannot make (a :class:`NerfEditError` for the status line); any by default."""
        return None

    def note(self, handles: tuple[EditorHandle, ...]) -> str:
        """A remark on the handles for the status line ("" for none)."""
        return ""

    def handle(self, indices: np.ndarray, fixed: bool) -> EditorHandle:
        """A new handle on ``indices``, pivot at their rest centroid."""
        return EditorHandle(indices, fixed, self.points[indices].mean(0))

    def spec_data(self, handles: tuple[EditorHandle, ...], selects: list[dict], folder: Path | None) -> dict:
        """The spec's keys for ``handles`` (handle ``i`` selected by ``selects[i]``), the backend's own ``keys`` as
        paths relative to ``folder`` (absolute when None)."""
        out = {key: _relative(value, folder) for key, value in self.keys.items()}
        out["handles"] = [
            {"select": select, **({"fixed": True} if h.fixed else {"transform": h.transform_spec()})}
            for h, select in zip(handles, selects)
        ]
        return out

    def handles_of(self, spec: EditSpec) -> tuple[EditorHandle, ...]:
        """The handles of a loaded ``spec`` (selections resolved against the control points)."""
        handles = []
        for handle in spec.handles:
            indices = handle.selection.indices(self.points, spec.source, self.faces)
            handles.append(EditorHandle.from_transform(indices, self.points[indices].mean(0), handle.transform))
        return tuple(handles)

    @abc.abstractmethod
    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        """The mesh (V,3) for ``spec`` at ``frame`` (``deformed``: the last preview, a warm start); sets
        :attr:`posed`."""

    def converge(
        self, spec: EditSpec, frame: int, deformed: np.ndarray, wanted: Callable[[], bool]
    ) -> tuple[np.ndarray, float, float, int] | None:
        """Finish the preview's solve → ``(vertices, energy before, energy after, iterations)``; None when the
        preview is already exact (or ``wanted()`` turned false between chunks)."""
        return None

    def posed_points(self, deformed: np.ndarray) -> np.ndarray:
        """The control points (P,3) as shown with the mesh at ``deformed`` (V,3)."""
        return self.posed

    def lines(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The overlay drawn as lines at :attr:`posed`: ``(points (P,3), edges (E,2))``, or None."""
        return None


def _relative(value, folder: Path | None):
    """A path value relative to ``folder`` (absolute without one); ``auto`` and other non-files as they are."""
    if not isinstance(value, Path):
        return value
    return str(value if folder is None else Path(os.path.relpath(value, folder)))


def _bound(config: DeformerConfig, rest: SurfaceMesh, data: dict):
    """The deformer of ``config`` bound to ``rest`` by the spec ``data`` (absolute paths)."""
    model = config.setup()
    model.bind(rest, parse_edit_spec({k: _relative(v, None) for k, v in data.items()}, model.spec_keys, "<editor>"))
    return model


class ArapBackend(EditingBackend):
    """Handles on the mesh's vertices; ``iterations`` per preview solve."""

    def __init__(self, rest: SurfaceMesh, config: DeformerConfig, keys: dict, iterations: int = PREVIEW_ITERATIONS):
        self.points, self.faces = rest.vertices, rest.faces
        super().__init__(rest, config, keys)
        self.iterations = iterations
        self.lock = threading.Lock()
        """Held by each solve: a settle on release (a worker thread) and the next drag's previews share the solver."""
        self._solver: tuple[bytes, ArapSolver] | None = None

    def check_handle(self, indices: np.ndarray, fixed: bool) -> None:
        if len(indices) == len(self.points):
            raise NerfEditError(
                f"mark: the selection covers the whole mesh ({len(indices)} vertices), nothing would be left to deform;"
                " deselect part of it"
            )

    def note(self, handles: tuple[EditorHandle, ...]) -> str:
        if any(not h.fixed for h in handles) and not any(h.fixed for h in handles):
            return (
                "; no fixed handle: the whole mesh moves rigidly with the moving handle (ARAP's minimum is the rigid"
                " motion) — mark a fixed handle to anchor it"
            )
        return ""

    def posed_points(self, deformed: np.ndarray) -> np.ndarray:
        return deformed

    def solver(self, indices: np.ndarray) -> ArapSolver:
        """The ARAP solver factored for these handle vertices (kept until they change)."""
        key = indices.tobytes()
        if self._solver is None or self._solver[0] != key:
            self._solver = (key, ArapSolver(self.points, self.faces, energy=self.config.energy, fixed=indices))
        return self._solver[1]

    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        indices, targets = spec.handle_targets(self.points, self.faces)
        with self.lock:
            result = self.solver(indices).solve(
                targets[frame],
                initial=deformed,
                max_iterations=self.iterations,
                tolerance=self.config.tolerance,
                anderson=0,
            )
        self.last_iterations = result.iterations
        return result.vertices

    def converge(self, spec, frame, deformed, wanted):
        indices, targets = spec.handle_targets(self.points, self.faces)
        with self.lock:
            solver = self.solver(indices)
            before = solver.energy(deformed)
        x, total = deformed, 0
        while total < self.config.max_iterations:
            if not wanted():
                return None
            with self.lock:
                result = solver.solve(
                    targets[frame], initial=x, max_iterations=CONVERGE_CHUNK, tolerance=self.config.tolerance
                )
            x, total = result.vertices, total + result.iterations
            if result.converged:
                break
        return x, before, solver.energy(x), total


class CageBackend(EditingBackend):
    """Handles on the cage's vertices (``keys["cage"]``: ``"auto"`` or a cage file's absolute path)."""

    what, file_keys, layer = "cage vertices", ("cage",), "cage"

    def __init__(self, rest: SurfaceMesh, config: DeformerConfig, keys: dict) -> None:
        keys = {"cage": "auto", **keys}
        self.model = _bound(config, rest, {**keys, "handles": [{"select": {"indices": [0]}, "fixed": True}]})
        self.points, self.faces = self.model.rest_cage.vertices, self.model.rest_cage.faces
        super().__init__(rest, config, keys)

    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        indices, targets = spec.handle_targets(self.points, self.faces)
        pose = self.points.copy()
        pose[indices] = targets[frame]
        self.model.deformed_cages, self.posed = pose[None], pose
        return self.model.deform()[0]

    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        f = self.faces
        edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
        return self.posed, edges


class SkeletonBackend(EditingBackend):
    """A handle is one joint of the skeleton (``keys["skeleton"]``, a JSON or BVH file's absolute path), turned and
    moved about its head: the spec's ``pose``."""

    what, scales, file_keys, layer = "joints", False, ("skeleton", "weights"), "skeleton"

    def __init__(self, rest: SurfaceMesh, config: DeformerConfig, keys: dict) -> None:
        if "skeleton" not in keys:
            raise NerfEditError("skeleton: give the skeleton to pose (nerfedit view --skeleton SKELETON.json)")
        self.model = _bound(config, rest, {**keys, "pose": {}})
        self.skeleton = self.model.skeleton
        self.points, self.faces = self.skeleton.heads, None
        super().__init__(rest, config, keys)

    def check_handle(self, indices: np.ndarray, fixed: bool) -> None:
        if fixed or len(indices) != 1:
            raise NerfEditError("mark: a skeleton handle is one moving joint (joints not posed keep their rest pose)")

    def spec_data(self, handles: tuple[EditorHandle, ...], selects: list[dict], folder: Path | None) -> dict:
        out = {key: _relative(value, folder) for key, value in self.keys.items()}
        out["pose"] = {
            self.skeleton.names[h.indices[0]]: {
                "rotate": h.rotate_spec,
                "translate": [float(v) for v in h.translate],
            }
            for h in handles
        }
        return out

    def handles_of(self, spec: EditSpec) -> tuple[EditorHandle, ...]:
        rotvec, trans = self.skeleton.parse_pose(spec.extra.get("pose", {}), spec.source)
        chosen = [self.skeleton.names.index(name) for name in spec.extra.get("pose", {})]
        return tuple(EditorHandle(np.array([j]), False, self.points[j], trans[j], rotvec[j]) for j in chosen)

    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        rotvec, trans = self.skeleton.parse_pose(spec.extra["pose"], spec.source)
        t = spec.times[frame]
        rot = Rotation.from_rotvec(t * rotvec).as_matrix()[None]
        self.model.rot, self.model.trans = self.skeleton.forward_kinematics(rot, t * trans[None])
        self.posed = np.einsum("jik,jk->ji", self.model.rot[0], self.points) + self.model.trans[0]
        return self.model.deform()[0]

    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        tails = np.einsum("jik,jk->ji", self.model.rot[0], self.skeleton.tails) + self.model.trans[0]
        n = len(self.points)
        return np.concatenate([self.posed, tails]), np.column_stack([np.arange(n), n + np.arange(n)])


BACKENDS: dict[str, type[EditingBackend]] = {"arap": ArapBackend, "cage": CageBackend, "skeleton": SkeletonBackend}


def backend_class(name: str) -> type[EditingBackend]:
    """The backend class of deformer ``name``; an error naming the ones there are."""
    if name not in BACKENDS:
        raise NerfEditError(f"view: the editor edits with {', '.join(BACKENDS)}; got --deformer {name}")
    return BACKENDS[name]


def editing_backend(name: str, rest: SurfaceMesh, keys: dict | None = None, config: DeformerConfig | None = None):
    """The backend of deformer ``name`` (its registry config's defaults unless ``config``) on ``rest``; ``keys``: the
    deformer's own spec keys, file paths as :class:`~pathlib.Path` (absolute)."""
    cls = backend_class(name)
    for key in keys or {}:
        if key not in cls.file_keys:
            raise NerfEditError(f"view: --{key} does not go with --deformer {name} (its handles grab {cls.what})")
    return cls(rest, config or discover(DEFORMERS).config_class(DEFORMERS, name)(), keys or {})
