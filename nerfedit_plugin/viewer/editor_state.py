"""The editor's model, without a window: the selection, the handles, undo/redo, the edit spec and the surface solve.

:class:`EditorState` holds a rest mesh, the current selection (vertex indices), the handles made from selections
(fixed or moving, each moving one with a similarity transform ``x ↦ c + s R (x − c) + τ``, ``c`` its selection's rest
centroid, exactly the spec's transform at t = 1) and an undo/redo history of snapshots. Everything the solvers see
goes through :meth:`EditorState.spec`, parsed as ``nerfedit edit`` parses the saved file, so the editor shows what
the command will compute:

- :meth:`EditorState.preview` re-solves the surface ARAP after a move with a solver prefactored for the current
  handle vertices (rebuilt only when they change), warm-started from the last result, a few iterations;
- :meth:`EditorState.settle` runs the deformer plugin on the spec exactly as ``nerfedit edit`` does (bind, deform):
  its frames are what a saved spec reproduces bit for bit.

Bad input raises :class:`~nerfedit_plugin.errors.NerfEditError` with a message for the status line and leaves the
state as it was.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import yaml
from scipy.sparse.csgraph import dijkstra
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.edit.selection_file import write_selection
from nerfedit_plugin.edit.spec import EditSpec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.arap import ArapResult, ArapSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import write_text

PREVIEW_ITERATIONS = 2
"""Local/global iterations per preview solve (each ~30–40 ms on the 28k-vertex bunny, 2 cores)."""


@dataclasses.dataclass(frozen=True)
class EditorHandle:
    """A handle: rest vertex ``indices`` (sorted, unique), ``fixed`` or moved by ``translate`` τ (3,), ``rotvec``
    (3,, radians) and ``scale`` s about ``center`` c (its selection's rest centroid)."""

    indices: np.ndarray
    fixed: bool
    center: np.ndarray
    translate: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    rotvec: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    @property
    def pivot(self) -> np.ndarray:
        """Where the handle's centroid is now (``c + τ``): the default pivot of a rotation or scale."""
        return self.center + self.translate

    def transform_spec(self) -> dict:
        """The spec's ``transform`` mapping (plain floats; ``rotate`` only when turned, ``scale`` only when not 1)."""
        out: dict = {"translate": [float(v) for v in self.translate]}
        angle = float(np.linalg.norm(self.rotvec))
        if angle > 0:
            axis = self.rotvec / angle
            out["rotate"] = {"axis": [float(v) for v in axis], "degrees": float(np.degrees(angle))}
            out["rotate"]["center"] = [float(v) for v in self.center]
        if self.scale != 1.0:
            out["scale"] = float(self.scale)
        return out


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What undo restores: the selection, the handles and the active (moved) handle's position in ``handles``."""

    selection: np.ndarray
    handles: tuple[EditorHandle, ...]
    active: int | None


class EditorState:
    """The editor's state for one rest ``mesh`` and a deformer's config (``deformer``; its plugin bound by
    :meth:`settle`). ``frames`` > 1 makes the spec an animation (frame 0 the rest pose); ``frame`` picks the one
    previewed. ``preview_iterations`` bounds each preview solve."""

    def __init__(
        self,
        mesh: SurfaceMesh,
        deformer: DeformerConfig,
        *,
        frames: int = 1,
        preview_iterations: int = PREVIEW_ITERATIONS,
    ) -> None:
        self.mesh, self.deformer = mesh, deformer
        self.frames, self.frame = frames, frames - 1
        self.preview_iterations = preview_iterations
        self.current = Snapshot(np.zeros(0, dtype=np.int64), (), None)
        self.undo_stack: list[Snapshot] = []
        self.redo_stack: list[Snapshot] = []
        self.deformed = mesh.vertices.copy()
        """(V,3) float64: the surface as last solved (rest while there are no handles)."""
        self.settled: np.ndarray | None = None
        """(frames,V,3) float64 from :meth:`settle` for the handles as they are now, else None."""
        self.last_result: ArapResult | None = None
        self._solver: tuple[bytes, ArapSolver] | None = None
        self._edges: sp.csr_matrix | None = None

    # ---- snapshots -----------------------------------------------------------------------------
    @property
    def selection(self) -> np.ndarray:
        return self.current.selection

    @property
    def handles(self) -> tuple[EditorHandle, ...]:
        return self.current.handles

    @property
    def active(self) -> EditorHandle | None:
        """The moving handle that moves act on (the last one made or chosen), or None."""
        return None if self.current.active is None else self.handles[self.current.active]

    def _commit(self, snapshot: Snapshot, record: bool) -> None:
        if record:
            self.undo_stack.append(self.current)
            self.redo_stack.clear()
        self.current = snapshot
        self.settled = None

    def undo(self) -> str:
        if not self.undo_stack:
            raise NerfEditError("undo: nothing to undo")
        self.redo_stack.append(self.current)
        self.current, self.settled = self.undo_stack.pop(), None
        return "undone"

    def redo(self) -> str:
        if not self.redo_stack:
            raise NerfEditError("redo: nothing to redo")
        self.undo_stack.append(self.current)
        self.current, self.settled = self.redo_stack.pop(), None
        return "redone"

    # ---- selections ----------------------------------------------------------------------------
    def select(self, indices, mode: str = "add") -> str:
        """Change the selection by picked vertex ``indices``: ``add`` to it, ``replace`` it, ``remove`` from it. An
        empty pick (a click on empty space) is an error."""
        picked = np.unique(np.asarray(indices, dtype=np.int64).ravel())
        if not len(picked):
            raise NerfEditError("pick: no surface under the cursor (nothing selected)")
        if picked[0] < 0 or picked[-1] >= self.mesh.n_vertices:
            raise NerfEditError(f"pick: vertex indices must lie in [0, {self.mesh.n_vertices})")
        now = self.selection
        chosen = {"add": np.union1d(now, picked), "replace": picked, "remove": np.setdiff1d(now, picked)}
        if mode not in chosen:
            raise NerfEditError(f"pick: unknown mode {mode!r} (add, replace, remove)")
        self._commit(dataclasses.replace(self.current, selection=chosen[mode].astype(np.int64)), True)
        return f"{len(self.selection)} vertices selected"

    def clear_selection(self) -> str:
        self._commit(dataclasses.replace(self.current, selection=np.zeros(0, dtype=np.int64)), True)
        return "selection cleared"

    def grow(self, radius: float) -> str:
        """Add every vertex within geodesic distance ``radius`` (along mesh edges) of the selection."""
        if not len(self.selection):
            raise NerfEditError("grow: select vertices first")
        if not (np.isfinite(radius) and radius > 0):
            raise NerfEditError(f"grow: the radius must be a positive distance, got {radius}")
        distance = dijkstra(self._edge_graph(), indices=self.selection, limit=radius, min_only=True)
        grown = np.flatnonzero(distance <= radius)
        self._commit(dataclasses.replace(self.current, selection=np.union1d(self.selection, grown)), True)
        return f"{len(self.selection)} vertices selected (grown by {radius:g})"

    def _edge_graph(self) -> sp.csr_matrix:
        if self._edges is None:
            faces, v = self.mesh.faces, self.mesh.vertices
            i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
            j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
            length = np.linalg.norm(v[i] - v[j], axis=1)
            n = self.mesh.n_vertices
            self._edges = (
                sp.coo_matrix((length, (i, j)), shape=(n, n))
                .tocsr()
                .maximum(sp.coo_matrix((length, (j, i)), shape=(n, n)).tocsr())
            )
        return self._edges

    # ---- handles -------------------------------------------------------------------------------
    def mark(self, fixed: bool) -> str:
        """Make the selection a fixed or a moving handle (the moving one becomes the active handle) and clear the
        selection. A selection of the whole mesh is refused: nothing would be left for the solver."""
        chosen = self.selection
        if not len(chosen):
            raise NerfEditError("mark: select vertices first (click, box or brush)")
        if len(chosen) == self.mesh.n_vertices:
            raise NerfEditError(
                f"mark: the selection covers the whole mesh ({len(chosen)} vertices), nothing would be left to deform;"
                " deselect part of it"
            )
        handle = EditorHandle(chosen, fixed, self.mesh.vertices[chosen].mean(0))
        handles = self.handles + (handle,)
        active = self.current.active if fixed else len(handles) - 1
        self._commit(Snapshot(np.zeros(0, dtype=np.int64), handles, active), True)
        kind = "fixed" if fixed else "moving"
        return f"handle {len(handles) - 1}: {kind}, {len(chosen)} vertices" + self._anchor_note()

    def activate(self, index: int) -> str:
        """Make moving handle ``index`` the one moves act on."""
        if not 0 <= index < len(self.handles) or self.handles[index].fixed:
            raise NerfEditError(f"handle {index}: no such moving handle")
        self._commit(dataclasses.replace(self.current, active=index), True)
        return f"handle {index} active"

    def remove_handle(self, index: int) -> str:
        if not 0 <= index < len(self.handles):
            raise NerfEditError(f"handle {index}: no such handle")
        handles = self.handles[:index] + self.handles[index + 1 :]
        active = self.current.active
        active = None if active == index else (active - 1 if active is not None and active > index else active)
        self._commit(dataclasses.replace(self.current, handles=handles, active=active), True)
        return f"handle {index} removed"

    def _anchor_note(self) -> str:
        moving = any(not h.fixed for h in self.handles)
        if moving and not any(h.fixed for h in self.handles):
            return (
                "; no fixed handle: the whole mesh moves rigidly with the moving handle (ARAP's minimum is the rigid"
                " motion) — mark a fixed handle to anchor it"
            )
        return ""

    # ---- moves of the active handle ------------------------------------------------------------
    def _moved(self, change, record: bool) -> str:
        handle = self.active
        if handle is None:
            raise NerfEditError("move: no moving handle (select vertices and mark them moving)")
        moved = change(handle)
        if not (np.isfinite(moved.translate).all() and np.isfinite(moved.rotvec).all() and moved.scale > 0):
            raise NerfEditError("move: the result is not a finite similarity (scale must stay > 0)")
        handles = list(self.handles)
        handles[self.current.active] = moved
        self._commit(dataclasses.replace(self.current, handles=tuple(handles)), record)
        return f"handle {self.current.active}: {json.dumps(moved.transform_spec())}" + self._anchor_note()

    def translate(self, delta, record: bool = True) -> str:
        """Move the active handle by ``delta`` (3,). ``record=False`` folds the move into the last undo step (the
        rest of a drag)."""
        delta = np.asarray(delta, dtype=np.float64).reshape(3)
        return self._moved(lambda h: dataclasses.replace(h, translate=h.translate + delta), record)

    def rotate(self, axis, degrees: float, pivot=None, record: bool = True) -> str:
        """Turn the active handle by ``degrees`` about ``axis`` through ``pivot`` (default: its current centroid)."""
        axis = np.asarray(axis, dtype=np.float64).reshape(3)
        if not np.linalg.norm(axis) > 0:
            raise NerfEditError("rotate: the axis is the zero vector")
        turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(degrees))

        def change(h: EditorHandle) -> EditorHandle:
            p = h.pivot if pivot is None else np.asarray(pivot, dtype=np.float64)
            rotvec = (turn * Rotation.from_rotvec(h.rotvec)).as_rotvec()
            return dataclasses.replace(
                h, rotvec=rotvec, translate=p + turn.apply(h.center + h.translate - p) - h.center
            )

        return self._moved(change, record)

    def scale(self, factor: float, pivot=None, record: bool = True) -> str:
        """Scale the active handle by ``factor`` (> 0) about ``pivot`` (default: its current centroid)."""
        if not (np.isfinite(factor) and factor > 0):
            raise NerfEditError(f"scale: the factor must be > 0, got {factor}")

        def change(h: EditorHandle) -> EditorHandle:
            p = h.pivot if pivot is None else np.asarray(pivot, dtype=np.float64)
            return dataclasses.replace(
                h, scale=h.scale * factor, translate=factor * (h.center + h.translate - p) + p - h.center
            )

        return self._moved(change, record)

    # ---- the spec ------------------------------------------------------------------------------
    def spec_data(self, selection_files: dict[int, str] | None = None) -> dict:
        """The edit spec (documented format) of the handles; handle ``i`` selects ``{"file": selection_files[i]}``
        when given, else its ``indices``."""
        if not self.handles:
            raise NerfEditError("spec: no handles yet (select vertices, mark them fixed or moving)")
        files = selection_files or {}
        handles = []
        for i, handle in enumerate(self.handles):
            select = {"file": files[i]} if i in files else {"indices": [int(k) for k in handle.indices]}
            handles.append(
                {"select": select, **({"fixed": True} if handle.fixed else {"transform": handle.transform_spec()})}
            )
        return {"handles": handles, "frames": self.frames}

    def spec(self) -> EditSpec:
        """:meth:`spec_data` parsed like a spec file (what the solvers use)."""
        return parse_edit_spec(self.spec_data(), self.deformer._target.spec_keys, "<editor>")

    def save(self, path: str | os.PathLike, selection_files: bool = True) -> list[Path]:
        """Write the spec to ``path`` (JSON, or YAML by suffix) and, with ``selection_files``, each handle's selection
        beside it as ``<stem>.handle<i>.selection.json`` (:func:`write_selection`) → the files written. Checked before
        anything is written (a folder that is missing or not writable is an error); each file is written atomically,
        so a failed save leaves what was there."""
        path = Path(path)
        folder = path.parent
        if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
            raise NerfEditError(f"save: cannot write into {folder} (missing or read-only); choose another place")
        if path.is_dir():
            raise NerfEditError(f"save: {path} is a folder; give a spec file name (edit.json)")
        names = (
            {i: f"{path.stem}.handle{i}.selection.json" for i in range(len(self.handles))} if selection_files else {}
        )
        data = self.spec_data(names)
        try:
            written = [
                write_selection(folder / names[i], self.mesh, h.indices)
                for i, h in enumerate(self.handles)
                if i in names
            ]
            text = (
                json.dumps(data, indent=2) if path.suffix.lower() == ".json" else yaml.safe_dump(data, sort_keys=False)
            )
            write_text(path, text + "\n")
        except OSError as exc:
            raise NerfEditError(f"save: cannot write {path} ({exc.strerror or exc})") from exc
        return [*written, path]

    # ---- solves ----------------------------------------------------------------------------------
    def targets(self) -> tuple[np.ndarray, np.ndarray]:
        """The handle vertices (H,) and their targets (frames, H, 3), as the spec resolves them."""
        return self.spec().handle_targets(self.mesh.vertices, self.mesh.faces)

    def preview(self) -> np.ndarray:
        """Re-solve the surface ARAP for the handles as they are (frame :attr:`frame`), warm-started from the last
        solve, at most :attr:`preview_iterations` iterations → :attr:`deformed` (V,3). No handles: the rest pose."""
        if not self.handles:
            self.deformed, self.last_result = self.mesh.vertices.copy(), None
            return self.deformed
        indices, targets = self.targets()
        result = self._arap(indices).solve(
            targets[self.frame],
            initial=self.deformed,
            max_iterations=self.preview_iterations,
            tolerance=getattr(self.deformer, "tolerance", 1e-6),
        )
        self.deformed, self.last_result = result.vertices, result
        return self.deformed

    def _arap(self, indices: np.ndarray) -> ArapSolver:
        """The ARAP solver factored for these handle vertices (kept until they change)."""
        key = indices.tobytes()
        if self._solver is None or self._solver[0] != key:
            energy = getattr(self.deformer, "energy", None)
            self._solver = (key, ArapSolver(self.mesh.vertices, self.mesh.faces, energy=energy, fixed=indices))
        return self._solver[1]

    def settle(self) -> np.ndarray:
        """Run the deformer plugin on the spec as ``nerfedit edit`` does → :attr:`settled` (frames,V,3); the
        previewed frame becomes :attr:`deformed`."""
        model = self.deformer.setup()
        model.bind(self.mesh, self.spec())
        self.settled = np.asarray(model.deform(), dtype=np.float64)
        self.deformed = self.settled[self.frame].copy()
        return self.settled

    def set_frame(self, frame: int) -> None:
        """Show frame ``frame`` of the animation (the settled one when settled)."""
        if not 0 <= frame < self.frames:
            raise NerfEditError(f"frame: {frame} out of range for {self.frames} frame(s)")
        self.frame = frame
        if self.settled is not None:
            self.deformed = self.settled[frame].copy()

    def set_frames(self, frames: int) -> str:
        """Make the spec an animation of ``frames`` frames (1: a single pose); the last frame is shown."""
        if frames < 1:
            raise NerfEditError(f"frames: expected an integer >= 1, got {frames}")
        self.frames, self.frame, self.settled = int(frames), int(frames) - 1, None
        return f"{frames} frame(s)"
