"""The editor's model, without a window: the selection, the handles, undo/redo, the edit spec and the solves.

:class:`EditorState` holds an :class:`~nerfedit_plugin.edit.editing.EditingBackend` (the chosen deformer's own:
what its handles grab, its control points), the current selection (control point indices), the handles made from
selections (:class:`~nerfedit_plugin.edit.editing.EditorHandle`) and an undo/redo history of snapshots. Everything
the solvers see goes through :meth:`EditorState.spec`, parsed as ``nerfedit edit`` parses the saved file, so the
editor shows what the command will compute (a handle's index selection is parsed, and the selections resolved
against the control points, once per handle set: a drag changes only the active handle's transform):

- :meth:`EditorState.preview` poses the mesh after a move through the backend (prefactored or bound once);
- :meth:`EditorState.preview_drag` poses one move of a drag as the backend shows it live: the mesh, or a
  :class:`~nerfedit_plugin.edit.editing.LiveView` of its own (:attr:`EditorState.live`; e.g. the coarse level of a
  large mesh), replaced by the mesh on release (:meth:`EditorState.released`);
- :meth:`EditorState.converge` finishes an iterative preview (settle on release) and reports the energy gap closed;
- :meth:`EditorState.settle` runs the deformer plugin on the spec exactly as ``nerfedit edit`` does (bind, deform):
  its frames are what a saved spec reproduces bit for bit.

Bad input raises :class:`~nerfedit_plugin.errors.NerfEditError` with a message for the status line and leaves the
state as it was.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import yaml
from scipy.sparse.csgraph import dijkstra
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.deformer import checked_frames, mesh_digest
from nerfedit_plugin.edit.editing import EditingBackend, EditorHandle, LiveView
from nerfedit_plugin.edit.selection import Selection, parse_selection
from nerfedit_plugin.edit.selection_file import write_selection
from nerfedit_plugin.edit.spec import EditSpec, Handle, load_edit_spec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import write_text
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.viewer.backends import backend_class, editing_backend


@dataclasses.dataclass(frozen=True)
class ResolvedSpec(EditSpec):
    """An :class:`EditSpec` whose :meth:`handle_targets` resolves its selections once per set of handle selections:
    ``resolved`` (shared by the specs of one editor) keeps, for the last ``(points, faces, selections)`` (the same
    objects), the handle points ``idx (H,)`` and per moving handle the rows it owns (the last handle listed wins) and
    its rest pivot; each call then only applies the transforms. Equal to :meth:`EditSpec.handle_targets`."""

    resolved: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    def handle_targets(self, points: np.ndarray, faces: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        selections = tuple(h.selection for h in self.handles)
        key = self.resolved.get("key")
        same = key is not None and key[0] is points and key[1] is faces and len(key[2]) == len(selections)
        if not (same and all(a is b for a, b in zip(key[2], selections))):
            if not self.handles:
                return super().handle_targets(points, faces)
            rest = np.asarray(points, dtype=np.float64)
            chosen = [h.selection.indices(rest, self.source, faces) for h in self.handles]
            owner = np.full(len(rest), -1)
            for h, sel in enumerate(chosen):
                owner[sel] = h
            idx = np.flatnonzero(owner >= 0)
            moving = [
                (h, np.searchsorted(idx, sel[owner[sel] == h]), rest[sel].mean(0))
                for h, sel in enumerate(chosen)
                if self.handles[h].transform is not None
            ]
            self.resolved.clear()
            self.resolved.update(key=(points, faces, selections), idx=idx, base=rest[idx], moving=moving)
        idx, base = self.resolved["idx"], self.resolved["base"]
        targets = np.repeat(base[None], self.frames, axis=0)
        for h, cols, pivot in self.resolved["moving"]:
            transform = self.handles[h].transform
            for f, t in enumerate(self.times):
                targets[f, cols] = transform.apply(base[cols], t, pivot)
        return idx, targets


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What undo restores: the selection, the handles and the active (moved) handle's position in ``handles``."""

    selection: np.ndarray
    handles: tuple[EditorHandle, ...]
    active: int | None


class EditorState:
    """The editor's state over ``backend`` (its rest :attr:`mesh`, its deformer's config :attr:`deformer`, bound by
    :meth:`settle`). ``frames`` > 1 makes the spec an animation (frame 0 the rest pose); ``frame`` picks the one
    previewed."""

    def __init__(self, backend: EditingBackend, *, frames: int = 1) -> None:
        self.backend = backend
        self.mesh, self.deformer = backend.rest, backend.config
        self.frames, self.frame = frames, frames - 1
        self.current = Snapshot(np.zeros(0, dtype=np.int64), (), None)
        self.undo_stack: list[Snapshot] = []
        self.redo_stack: list[Snapshot] = []
        self.deformed = self.mesh.vertices.copy()
        """(V,3) float64: the surface as last solved (rest while there are no handles)."""
        self.live: LiveView | None = None
        """What a drag shows instead of the mesh since the last :meth:`preview_drag` (:attr:`deformed` is then the
        mesh as last posed before it), else None: the mesh at :attr:`deformed` is shown."""
        self.settled: np.ndarray | None = None
        """(frames,V,3) float64 from :meth:`settle` for the handles as they are now, else None."""
        self._edges: sp.csr_matrix | None = None
        self._selections: list[tuple[np.ndarray, Selection]] = []  # per handle: its indices array, parsed
        self._resolved: dict = {}  # ResolvedSpec.resolved of this editor's specs

    @classmethod
    def open(
        cls,
        name: str,
        mesh: SurfaceMesh,
        path: str | os.PathLike,
        keys: dict | None = None,
        source_to_world: np.ndarray | None = None,
    ) -> EditorState:
        """The state of the edit spec at ``path`` for deformer ``name`` on ``mesh``, to keep editing: its handles
        (selection files included), frames and the deformer's own keys (``keys``, files given on the command line,
        override them), shown settled; a ``frame: source`` spec needs the run's ``source_to_world``."""
        config = discover(DEFORMERS).config_class(DEFORMERS, name)()
        backend = backend_class(name, config)  # refuses a deformer that offers no editor backend
        spec = load_edit_spec(path, config._target.spec_keys)
        if spec.frame == "source":
            if source_to_world is None:
                raise NerfEditError(f"{path}: frame: source needs the run it was made for (--run RUN)")
            spec = spec.in_world(source_to_world)
        own = backend.keys_of(spec)
        state = cls(editing_backend(name, mesh, {**own, **(keys or {})}, config), frames=spec.frames)
        handles = state.backend.handles_of(spec)
        moving = [i for i, h in enumerate(handles) if not h.fixed]
        state.current = Snapshot(np.zeros(0, dtype=np.int64), handles, moving[-1] if moving else None)
        state.preview()  # poses the control points
        state.settle()  # shows the spec's own solve
        return state

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
        count = len(self.backend.points)
        if picked[0] < 0 or picked[-1] >= count:
            raise NerfEditError(f"pick: {self.backend.what} indices must lie in [0, {count})")
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
        if self.backend.faces is None:
            raise NerfEditError(f"grow: {self.backend.what} have no surface to grow along")
        if not (np.isfinite(radius) and radius > 0):
            raise NerfEditError(f"grow: the radius must be a positive distance, got {radius}")
        distance = dijkstra(self._edge_graph(), indices=self.selection, limit=radius, min_only=True)
        grown = np.flatnonzero(distance <= radius)
        self._commit(dataclasses.replace(self.current, selection=np.union1d(self.selection, grown)), True)
        return f"{len(self.selection)} vertices selected (grown by {radius:g})"

    def _edge_graph(self) -> sp.csr_matrix:
        if self._edges is None:
            faces, v = self.backend.faces, self.backend.points
            i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
            j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
            length = np.linalg.norm(v[i] - v[j], axis=1)
            n = len(v)
            self._edges = (
                sp.coo_matrix((length, (i, j)), shape=(n, n))
                .tocsr()
                .maximum(sp.coo_matrix((length, (j, i)), shape=(n, n)).tocsr())
            )
        return self._edges

    # ---- handles -------------------------------------------------------------------------------
    def mark(self, fixed: bool) -> str:
        """Make the selection a fixed or a moving handle (the moving one becomes the active handle) and clear the
        selection; the backend refuses what its deformer cannot take (``EditingBackend.check_handle``)."""
        chosen = self.selection
        if not len(chosen):
            raise NerfEditError(f"mark: select {self.backend.what} first (click, box or brush)")
        self.backend.check_handle(chosen, fixed)
        handle = self.backend.handle(chosen, fixed)
        handles = self.handles + (handle,)
        active = self.current.active if fixed else len(handles) - 1
        self._commit(Snapshot(np.zeros(0, dtype=np.int64), handles, active), True)
        kind = "fixed" if fixed else "moving"
        return f"handle {len(handles) - 1}: {kind}, {len(chosen)} {self.backend.what}" + self.backend.note(handles)

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
        return f"handle {self.current.active}: {json.dumps(moved.transform_spec())}" + self.backend.note(self.handles)

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
        if not self.backend.scales:
            raise NerfEditError(f"scale: {self.backend.what} turn and move, they do not scale")
        if not (np.isfinite(factor) and factor > 0):
            raise NerfEditError(f"scale: the factor must be > 0, got {factor}")

        def change(h: EditorHandle) -> EditorHandle:
            p = h.pivot if pivot is None else np.asarray(pivot, dtype=np.float64)
            return dataclasses.replace(
                h, scale=h.scale * factor, translate=factor * (h.center + h.translate - p) + p - h.center
            )

        return self._moved(change, record)

    # ---- the spec ------------------------------------------------------------------------------
    def spec_data(self, selection_files: dict[int, str] | None = None, folder: Path | None = None) -> dict:
        """The edit spec (documented format) of the handles; handle ``i`` selects ``{"file": selection_files[i]}``
        when given, else its ``indices``; the deformer's files are named relative to ``folder`` (absolute when
        None)."""
        if not self.handles:
            raise NerfEditError(f"spec: no handles yet (select {self.backend.what}, mark them fixed or moving)")
        files = selection_files or {}
        selects = [
            {"file": files[i]} if i in files else {"indices": h.indices.tolist()} for i, h in enumerate(self.handles)
        ]
        return {**self.backend.spec_data(self.handles, selects, folder), "frames": self.frames}

    def spec(self) -> EditSpec:
        """:meth:`spec_data` parsed like a spec file (what the solvers use), as a :class:`ResolvedSpec`. With the
        default spec layout (:meth:`EditingBackend.spec_data`: spec handle ``i`` is handle ``i``) each handle's
        ``indices`` selection is parsed once while its indices array is the same object, and the rest of the spec
        is parsed afresh; the result equals parsing :meth:`spec_data`."""
        if not self.handles or type(self.backend).spec_data is not EditingBackend.spec_data:
            parsed = parse_edit_spec(self.spec_data(), self.backend.spec_keys, "<editor>")
        else:
            first = [{"indices": [int(h.indices[0])]} for h in self.handles]  # stand-ins, replaced below
            data = {**self.backend.spec_data(self.handles, first, None), "frames": self.frames}
            parsed = parse_edit_spec(data, self.backend.spec_keys, "<editor>")
            kept = self._selections[: len(self.handles)]
            self._selections = [
                kept[i] if i < len(kept) and kept[i][0] is h.indices else (h.indices, self._selection(i, h.indices))
                for i, h in enumerate(self.handles)
            ]
            handles = tuple(
                Handle(selection, h.transform) for (_, selection), h in zip(self._selections, parsed.handles)
            )
            parsed = dataclasses.replace(parsed, handles=handles)
        fields = {f.name: getattr(parsed, f.name) for f in dataclasses.fields(EditSpec)}
        return ResolvedSpec(**fields, resolved=self._resolved)

    @staticmethod
    def _selection(i: int, indices: np.ndarray) -> Selection:
        """Handle ``i``'s selection of ``indices`` as :func:`parse_edit_spec` parses it from :meth:`spec_data`."""
        return parse_selection({"indices": indices.tolist()}, "<editor>", f"handles[{i}].select", Path("."))

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
        controls = None if self.backend.faces is None else SurfaceMesh(self.backend.points, self.backend.faces)
        names = (
            {i: f"{path.stem}.handle{i}.selection.json" for i in range(len(self.handles))}
            if selection_files and controls is not None
            else {}
        )
        data = self.spec_data(names, folder)
        try:
            written = [
                write_selection(folder / names[i], controls, h.indices)
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
        """The handles' control points (H,) and their targets (frames, H, 3), as the spec resolves them."""
        return self.spec().handle_targets(self.backend.points, self.backend.faces)

    def preview(self) -> np.ndarray:
        """Pose the mesh for the handles as they are (frame :attr:`frame`) through the backend, warm-started from the
        last preview → :attr:`deformed` (V,3). No handles: the rest pose."""
        self.live = None
        if not self.handles:
            self.deformed, self.backend.posed = self.mesh.vertices.copy(), self.backend.points
            return self.deformed
        self.deformed = self.backend.preview(self.spec(), self.frame, self.deformed)
        return self.deformed

    def preview_drag(self) -> np.ndarray | LiveView:
        """One move of a drag through :meth:`~nerfedit_plugin.edit.editing.EditingBackend.preview_drag` → the mesh
        (V,3) (:attr:`deformed`, as :meth:`preview` poses it) or the backend's :class:`LiveView` (:attr:`live`)."""
        if not self.handles:
            return self.preview()
        shown = self.backend.preview_drag(self.spec(), self.frame, self.deformed)
        if isinstance(shown, LiveView):
            self.live = shown
        else:
            self.live, self.deformed = None, shown
        return shown

    def released(self, done: tuple | None) -> np.ndarray:
        """After a drag's moves, the mesh shown on release → :attr:`deformed` (:attr:`live` cleared): ``done`` (what
        :meth:`converge` returned) its vertices; None: the mesh as it is, posed by :meth:`preview` when a live view
        was shown."""
        if done is not None:
            self.deformed, self.live = done[0], None
        elif self.live is not None:
            self.preview()
        return self.deformed

    def converge(self, wanted: Callable[[], bool] = lambda: True) -> tuple[np.ndarray, float, float, int] | None:
        """Finish the last preview's solve (settle on release) → ``(vertices (V,3), energy before, energy after,
        iterations)``, or None when the preview is exact or ``wanted()`` turned false; :attr:`deformed` is left to
        the caller (a worker thread hands it over only if the handles did not change meanwhile)."""
        if not self.handles:
            return None
        return self.backend.converge(self.spec(), self.frame, self.deformed, wanted)

    @property
    def posed_points(self) -> np.ndarray:
        """The control points (P,3) as shown (:meth:`~nerfedit_plugin.edit.editing.EditingBackend.posed_points`)."""
        return self.backend.posed_points(self.deformed)

    def settle(self) -> np.ndarray:
        """Run the deformer plugin on the spec as ``nerfedit edit`` does → :attr:`settled` (frames,V,3); the
        previewed frame becomes :attr:`deformed`."""
        model, spec, digest = self.deformer.setup(), self.spec(), mesh_digest(self.mesh)
        model.bind(self.mesh, spec)
        self.settled = checked_frames(model, model.deform(), self.mesh, spec, digest)
        self.deformed, self.live = self.settled[self.frame].copy(), None
        return self.settled

    def set_frame(self, frame: int) -> None:
        """Show frame ``frame`` of the animation (the settled one when settled)."""
        if not 0 <= frame < self.frames:
            raise NerfEditError(f"frame: {frame} out of range for {self.frames} frame(s)")
        self.frame = frame
        if self.settled is not None:
            self.deformed, self.live = self.settled[frame].copy(), None

    def set_frames(self, frames: int) -> str:
        """Make the spec an animation of ``frames`` frames (1: a single pose); the last frame is shown."""
        if frames < 1:
            raise NerfEditError(f"frames: expected an integer >= 1, got {frames}")
        self.frames, self.frame, self.settled = int(frames), int(frames) - 1, None
        return f"{frames} frame(s)"
