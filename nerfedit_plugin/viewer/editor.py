"""The interactive editor window (``nerfedit view --mesh MESH`` / ``--run RUN``): Open3D ``gui`` with a
``SceneWidget``, a side panel and a status line, driving an :class:`~nerfedit_plugin.viewer.editor_state.EditorState`.

What is picked depends on the deformer (``--deformer``): the control points of its editing backend
(:attr:`Deformer.editor <nerfedit_plugin.edit.deformer.Deformer.editor>`: mesh vertices, or points of its own, drawn
with its overlay layer). Mouse (in the 3-D view): drag orbits; **Ctrl+click** picks the vertex under the cursor,
**Ctrl+drag** selects the visible vertices in a box, **Alt+drag** brushes them; **Shift+drag** moves the active
moving handle in the view plane (each move re-poses through the backend's drag preview: the mesh, or what the backend
shows live instead — for ARAP on a mesh above the multiresolution threshold, the coarse level as solved, its handles
on their targets); when the drag ends an iterative preview's solve is finished in a worker thread and the mesh shown
(settle on release; the status line reports the energy gap closed). Keys: **F** / **M** mark the
selection fixed / moving, **G** grows it by the panel's geodesic radius, **Esc** clears it, arrows nudge the active
handle in the view plane and **PgUp/PgDn** along the view direction, **Q/E** turn it ±5° about the view axis,
**+/−** scale it ×1.05, **Z / Y** undo / redo, **Enter** settles (the exact solve ``nerfedit edit`` runs), **R**
renders the field (with ``--run``), **S** saves the spec. Every error goes to the status line and stderr; the editor
keeps running.

A script (``nerfedit view --script STEPS.json``) runs the same actions without a person, one step per frame: a list
of ``{"pick": [i, …]}``, ``{"click": [x, y]}``, ``{"box": [x0, y0, x1, y1]}``, ``{"brush": [[x, y], …], "radius":
px}``, ``{"grow": r}``, ``{"mark": "fixed" | "moving"}``, ``{"drag": [dx, dy]}``, ``{"translate": [x, y, z]}``,
``{"rotate": {"axis": […], "degrees": d, "pivot": […]}}``, ``{"scale": k}``, ``{"undo": true}``, ``{"redo": true}``,
``{"settle": true}``, ``{"render": true}``, ``{"save": "edit.json"}``, ``{"screenshot": "view.png"}``,
``{"layer": {"rest": true, …}}``, ``{"frame": i}``, ``{"frames": n}``, ``{"quit": true}`` (pixels in the 3-D view's
coordinates); each move is settled (on release) before the next step. A step of another kind is an error before the
window opens (:func:`check_script`).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import open3d as o3d
import open3d.visualization.gui as gui
import open3d.visualization.rendering as rendering

from nerfedit_plugin.data.datasets import to_uint8
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_path
from nerfedit_plugin.viewer.editor_state import EditorState
from nerfedit_plugin.viewer.field_preview import FieldPreview
from nerfedit_plugin.viewer.layers import DEFAULT_FRONT, _edges, _rotate_y_to, ensure_runtime_dir
from nerfedit_plugin.viewer.picking import Picker, View

EDITOR_LAYERS = ("rest", "deformed", "handles", "proxy", "deformed-proxy")
SHOWN = {"rest": False, "deformed": True, "handles": True, "proxy": False, "deformed-proxy": False}
COLORS = {
    "fixed": (0.15, 0.35, 0.95),
    "moving": (0.95, 0.2, 0.15),
    "selection": (0.95, 0.8, 0.1),
    "controls": (0.1, 0.6, 0.3),
}
BRUSH_RADIUS = 12.0
"""Brush radius in pixels."""
SCRIPT_WARMUP_TICKS = 20
"""Window ticks (~10 ms each) before a script's first step: the first frames must have been drawn."""
NUDGE = 0.01
"""Keyboard nudge, as a share of the rest mesh's bounding-box diagonal."""


def _material(shader: str, point_size: float = 1.0, color=(1.0, 1.0, 1.0, 1.0)) -> rendering.MaterialRecord:
    material = rendering.MaterialRecord()
    material.shader, material.point_size, material.base_color = shader, point_size, color
    return material


class Editor:
    """One editor window over ``state``; ``preview`` renders the field (None without a run); ``spec_path`` is where
    **S** saves; ``up`` the world's up direction; ``script`` a list of steps run after the first frame."""

    def __init__(
        self,
        state: EditorState,
        *,
        preview: FieldPreview | None = None,
        spec_path: Path = Path("edit.json"),
        up=(0.0, 1.0, 0.0),
        script: list[dict] | None = None,
        width: int = 1280,
        height: int = 800,
    ) -> None:
        self.state, self.preview, self.up = state, preview, np.asarray(up, dtype=np.float64)
        self.script = list(script or [])
        self.shown = dict(SHOWN)
        self.last_update_ms: float | None = None
        self._drag: dict | None = None  # the mouse gesture under way
        self._pending = np.zeros(2)  # handle drag in pixels not yet solved
        self._flush_posted = False
        self._proxy: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # rest, deformed, tets of the last render
        self._shown = ShownMesh(state.mesh.faces)  # the deformed layer's tensor meshes (moves update them)
        layer = state.backend.layer
        self.layers = EDITOR_LAYERS + ((layer,) if layer else ())
        self.shown.update({layer: True} if layer else {})
        self.app = gui.Application.instance
        self.window = self.app.create_window("nerfedit editor", width, height)
        self.scene = gui.SceneWidget()
        self.scene.scene = rendering.Open3DScene(self.window.renderer)
        self.scene.scene.set_background((1.0, 1.0, 1.0, 1.0))
        self.scene.set_on_mouse(self._on_mouse)
        self.scene.set_on_key(self._on_key)
        self.panel = self._build_panel(spec_path)
        self.window.add_child(self.scene)
        self.window.add_child(self.panel)
        self.window.set_on_layout(self._layout)
        self._draw_all()
        self._reset_camera()
        self._ticks, self._busy = 0, False
        self.window.set_on_tick_event(self._tick)
        self.window.set_on_close(self._exit)

    # ---- layout ------------------------------------------------------------------------------------
    def _build_panel(self, spec_path: Path) -> gui.Vert:
        em = self.window.theme.font_size
        panel = gui.Vert(0.25 * em, gui.Margins(0.5 * em, 0.5 * em, 0.5 * em, 0.5 * em))
        panel.add_child(gui.Label("Layers"))
        self.checks = {}
        for name in self.layers:
            box = gui.Checkbox(name)
            box.checked = self.shown[name]
            box.set_on_checked(lambda on, name=name: self._act(lambda: self.set_layer(name, on)))
            self.checks[name] = box
            panel.add_child(box)
        panel.add_child(gui.Label("Frame"))
        self.frame_slider = gui.Slider(gui.Slider.INT)
        self.frame_slider.set_limits(0, max(self.state.frames - 1, 1))
        self.frame_slider.int_value = self.state.frame
        self.frame_slider.set_on_value_changed(lambda v: self._act(lambda: self._set_frame(int(v))))
        self.frames_edit = gui.NumberEdit(gui.NumberEdit.INT)
        self.frames_edit.int_value = self.state.frames
        self.frames_edit.set_on_value_changed(lambda v: self._act(lambda: self._set_frames(int(v))))
        panel.add_child(self._row(self.frame_slider, gui.Label("of"), self.frames_edit))
        panel.add_child(gui.Label("Selection"))
        self.radius = gui.NumberEdit(gui.NumberEdit.DOUBLE)
        self.radius.double_value = 0.02 * self.state.mesh.bbox_diagonal
        panel.add_child(self._row(self._button("Grow (G)", self._grow), self.radius))
        panel.add_child(
            self._row(
                self._button("Fixed (F)", lambda: self.state.mark(True)),
                self._button("Moving (M)", lambda: self.state.mark(False)),
                self._button("Clear", self.state.clear_selection),
            )
        )
        panel.add_child(gui.Label("Move the active handle"))
        self.numbers = {name: self._vector(name) for name in ("translate", "axis", "pivot")}
        self.degrees, self.factor = gui.NumberEdit(gui.NumberEdit.DOUBLE), gui.NumberEdit(gui.NumberEdit.DOUBLE)
        self.factor.double_value = 1.0
        panel.add_child(self._row(self._button("Translate", self._translate_numbers), *self.numbers["translate"]))
        panel.add_child(self._row(gui.Label("axis"), *self.numbers["axis"]))
        panel.add_child(self._row(gui.Label("pivot"), *self.numbers["pivot"]))
        panel.add_child(self._row(self._button("Rotate", self._rotate_numbers), self.degrees, gui.Label("deg")))
        panel.add_child(self._row(self._button("Scale", self._scale_numbers), self.factor))
        panel.add_child(
            self._row(
                self._button("Undo (Z)", self.state.undo),
                self._button("Redo (Y)", self.state.redo),
                self._button("Settle", self.settle),
            )
        )
        self.spec_path = gui.TextEdit()
        self.spec_path.text_value = str(spec_path)
        panel.add_child(
            self._row(self._button("Save (S)", lambda: self.save(self.spec_path.text_value)), self.spec_path)
        )
        render = self._button("Render (R)", self.render)
        render.enabled = self.preview is not None
        panel.add_child(render)
        self.images = (gui.ImageWidget(), gui.ImageWidget())
        panel.add_child(self._row(gui.Label("field"), self.images[0], gui.Label("edited"), self.images[1]))
        self.status = gui.Label("Ctrl+click: pick · Ctrl+drag: box · Alt+drag: brush · Shift+drag: move")
        panel.add_child(self.status)
        return panel

    def _row(self, *widgets) -> gui.Horiz:
        row = gui.Horiz(0.25 * self.window.theme.font_size)
        for widget in widgets:
            row.add_child(widget)
        return row

    def _button(self, text: str, action: Callable[[], str | None]) -> gui.Button:
        button = gui.Button(text)
        button.set_on_clicked(lambda: self._act(action))
        return button

    def _vector(self, name: str) -> list[gui.NumberEdit]:
        edits = [gui.NumberEdit(gui.NumberEdit.DOUBLE) for _ in range(3)]
        if name == "axis":
            edits[2].double_value = 1.0
        return edits

    def _layout(self, context) -> None:
        rect = self.window.content_rect
        width = min(int(26 * self.window.theme.font_size), rect.width // 2)
        self.scene.frame = gui.Rect(rect.x, rect.y, rect.width - width, rect.height)
        self.panel.frame = gui.Rect(rect.get_right() - width, rect.y, width, rect.height)

    def _reset_camera(self) -> None:
        """Frame the rest mesh (the same view whether an opened spec has moved it or not)."""
        rest = self.state.mesh.vertices
        box = o3d.geometry.AxisAlignedBoundingBox(rest.min(0), rest.max(0))
        centre = box.get_center()
        self.scene.setup_camera(60.0, box, centre)
        front = _rotate_y_to(self.up / np.linalg.norm(self.up), DEFAULT_FRONT)
        eye = centre + front / np.linalg.norm(front) * 1.6 * float(np.linalg.norm(box.get_extent()))
        self.scene.look_at(centre, eye, self.up)

    def _exit(self) -> bool:
        """End the process when the window closes: Open3D 0.20 crashes while tearing its renderer down (seen under
        llvmpipe), and every output is already written (atomically) by then."""
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)

    # ---- actions -----------------------------------------------------------------------------------
    def _act(self, action: Callable[[], str | None], redraw: bool = True) -> bool:
        """Run an action; its message, or its error, goes to the status line (errors also to stderr). True when
        it succeeded."""
        try:
            message = action()
        except NerfEditError as exc:
            self.say(str(exc), error=True)
            return False
        if message:
            self.say(message)
        if redraw:
            self._after_change()
        return True

    def say(self, message: str, error: bool = False) -> None:
        self.status.text = message
        if error or "no fixed handle" in message:
            print(f"nerfedit view: {message}", file=sys.stderr, flush=True)
        self.window.post_redraw()

    def _after_change(self) -> None:
        """Re-solve after the handles changed and redraw."""
        try:
            self.state.preview()
        except NerfEditError as exc:
            self.say(str(exc), error=True)
        self._draw_all()

    def view(self) -> View:
        camera, frame = self.scene.scene.camera, self.scene.frame
        return View(
            np.asarray(camera.get_view_matrix()), np.asarray(camera.get_projection_matrix()), frame.width, frame.height
        )

    def picker(self) -> Picker:
        """Picks the control points as shown (the backend's posed points)."""
        return Picker(self.state.posed_points, self.state.backend.faces)

    def click(self, x: float, y: float) -> str:
        found = self.picker().click(self.view(), x, y)
        if found is None:
            raise NerfEditError(f"pick: no surface under the cursor at ({x:.0f}, {y:.0f})")
        return self.state.select([found])

    def box(self, corner, opposite) -> str:
        return self.state.select(self.picker().box(self.view(), corner, opposite))

    def brush(self, path, radius: float = BRUSH_RADIUS) -> str:
        return self.state.select(self.picker().brush(self.view(), np.asarray(path), radius))

    def drag(self, dx: float, dy: float, record: bool = True) -> str:
        """Move the active handle by a drag of ``(dx, dy)`` pixels in the view plane through its centroid."""
        handle = self.state.active
        if handle is None:
            raise NerfEditError("move: no moving handle (select vertices and mark them moving)")
        return self.state.translate(self.view().plane_motion(handle.pivot, dx, dy), record)

    def _grow(self) -> str:
        return self.state.grow(self.radius.double_value)

    def _translate_numbers(self) -> str:
        return self.state.translate([e.double_value for e in self.numbers["translate"]])

    def _rotate_numbers(self) -> str:
        pivot = [e.double_value for e in self.numbers["pivot"]]
        axis = [e.double_value for e in self.numbers["axis"]]
        return self.state.rotate(axis, self.degrees.double_value, pivot if any(pivot) else None)

    def _scale_numbers(self) -> str:
        return self.state.scale(self.factor.double_value)

    def _set_frame(self, frame: int) -> str:
        self.state.set_frame(frame)
        return f"frame {frame}"

    def _set_frames(self, frames: int) -> str:
        message = self.state.set_frames(frames)
        self.frame_slider.set_limits(0, max(frames - 1, 1))
        self.frame_slider.int_value = self.state.frame
        return message

    def set_layer(self, name: str, on: bool) -> str:
        if name not in self.shown:
            raise NerfEditError(f"layer: unknown layer {name!r} (choose from {', '.join(self.layers)})")
        self.shown[name] = self.checks[name].checked = bool(on)
        if name in ("proxy", "deformed-proxy") and on and self._proxy is None:
            return f"{name}: rendered once the field is rendered (R, with --run)"
        return f"{name} {'shown' if on else 'hidden'}"

    def settle(self) -> str:
        start = time.perf_counter()
        self.state.settle()
        return f"settled in {time.perf_counter() - start:.2f} s: the exact solve `nerfedit edit` reproduces"

    def save(self, path: str) -> str:
        self.state.settle()  # what is shown is what the saved spec reproduces
        written = self.state.save(path)
        return f"saved {written[-1]} ({len(written) - 1} selection file(s)); shown: its exact solve"

    def render(self) -> str:
        if self.preview is None:
            raise NerfEditError("render: needs a trained field (open the editor with --run RUN)")
        start = time.perf_counter()
        self.state.released(None)  # the mesh, posed, when a drag's live view is shown (keys during a drag)
        view = self.view()
        before = self.preview.unedited(view)
        after = self.preview.edited(view, self.state.deformed)
        lifted = self.preview.last
        self._proxy = (lifted.rest_vertices, lifted.deformed_vertices[0], lifted.tets)
        for widget, image in zip(self.images, (before, after)):
            widget.update_image(o3d.geometry.Image(np.ascontiguousarray(to_uint8(image))))
        return f"rendered {after.shape[1]}×{after.shape[0]} in {time.perf_counter() - start:.2f} s"

    def screenshot(self, path: str, then: Callable[[], None]) -> None:
        """Write the 3-D view to ``path`` (PNG, atomically), then call ``then``."""

        def done(image) -> None:
            import skimage.io

            try:
                with atomic_path(path) as tmp:
                    skimage.io.imsave(tmp, np.asarray(image), check_contrast=False)
            except OSError as exc:
                print(f"nerfedit view: screenshot: cannot write {path} ({exc})", file=sys.stderr, flush=True)
            finally:
                then()

        self.scene.scene.scene.render_to_image(done)
        self.window.post_redraw()

    # ---- drawing -----------------------------------------------------------------------------------
    def _draw_all(self) -> None:
        start = time.perf_counter()
        scene, state = self.scene.scene, self.state
        for name in ("rest", "deformed", "handles", "selection", "proxy", "deformed-proxy", "controls"):
            if scene.has_geometry(name):
                scene.remove_geometry(name)
        lit = _material("defaultLit")
        if self.shown["rest"]:
            scene.add_geometry("rest", _mesh(state.mesh.vertices, state.mesh.faces, (0.8, 0.8, 0.78)), lit)
        self._shown.mesh = None  # rebuilt, normals included
        if self.shown["deformed"]:
            scene.add_geometry("deformed", self._shown.update(state, normals=True), lit)
        self._draw_controls()
        if len(state.selection):
            parts = [(state.selection, COLORS["selection"])]
            scene.add_geometry("selection", _points(state.posed_points, parts), _material("defaultUnlit", 6.0))
        if self._proxy is not None:
            rest, deformed, tets = self._proxy
            lines = _material("unlitLine", 1.0)
            for name, vertices, color in (
                ("proxy", rest, (0.5, 0.5, 0.55)),
                ("deformed-proxy", deformed, (0.9, 0.55, 0.2)),
            ):
                if self.shown[name]:
                    scene.add_geometry(name, o3d.t.geometry.LineSet.from_legacy(_edges(vertices, tets, color)), lines)
        self.last_update_ms = 1e3 * (time.perf_counter() - start)
        self.window.post_redraw()

    def _draw_controls(self) -> None:
        """(Re)draw the handles at the posed control points and the backend's overlay lines."""
        scene, state = self.scene.scene, self.state
        for name in ("handles", "controls"):
            if scene.has_geometry(name):
                scene.remove_geometry(name)
        if self.shown["handles"] and state.handles:
            live = state.live
            if live is None:
                points = state.posed_points
                parts = [(h.indices, COLORS["fixed" if h.fixed else "moving"]) for h in state.handles]
            else:
                points = live.vertices
                parts = [(i, COLORS[kind]) for i, kind in ((live.fixed, "fixed"), (live.moving, "moving")) if len(i)]
            if parts:
                scene.add_geometry("handles", _points(points, parts), _material("defaultUnlit", 6.0))
        lines = state.backend.lines()
        if lines is not None and self.shown[state.backend.layer]:
            points, edges = lines
            wire = o3d.t.geometry.LineSet(
                o3d.core.Tensor(points.astype(np.float32)), o3d.core.Tensor(edges.astype(np.int32))
            )
            wire.line.colors = o3d.core.Tensor(np.tile(np.float32(COLORS["controls"]), (len(edges), 1)))
            scene.add_geometry("controls", wire, _material("unlitLine", 2.0))

    def update_deformed(self, normals: bool = False) -> float:
        """Redraw the deformed layer — the mesh, or the state's live view during a drag, its vertex positions set in
        the kept tensor mesh (:class:`ShownMesh`); its normals recomputed only with ``normals`` (a drag keeps the last
        ones) — and the handles and overlay → seconds taken."""
        start = time.perf_counter()
        scene, state = self.scene.scene, self.state
        if self.shown["deformed"]:
            shown = self._shown.update(state, normals)
            scene.remove_geometry("deformed")
            scene.add_geometry("deformed", shown, _material("defaultLit"))
        self._draw_controls()
        self.window.post_redraw()
        return time.perf_counter() - start

    # ---- input -------------------------------------------------------------------------------------
    def _on_mouse(self, event) -> gui.Widget.EventCallbackResult:
        frame = self.scene.frame
        x, y = event.x - frame.x, event.y - frame.y
        ctrl, alt = event.is_modifier_down(gui.KeyModifier.CTRL), event.is_modifier_down(gui.KeyModifier.ALT)
        shift = event.is_modifier_down(gui.KeyModifier.SHIFT)
        kind = event.type
        if kind == gui.MouseEvent.Type.BUTTON_DOWN and (ctrl or alt or shift):
            mode = "move" if shift else ("brush" if alt else "pick")
            self._drag = {"mode": mode, "start": (x, y), "last": (x, y), "path": [(x, y)], "moved": False}
            return gui.Widget.EventCallbackResult.CONSUMED
        if self._drag is None:
            return gui.Widget.EventCallbackResult.IGNORED
        gesture = self._drag
        if kind == gui.MouseEvent.Type.DRAG:
            if gesture["mode"] == "move":
                self._pending += (x - gesture["last"][0], y - gesture["last"][1])
                if not self._flush_posted:
                    self._flush_posted = True
                    self.app.post_to_main_thread(self.window, self._flush_drag)
            gesture["path"].append((x, y))
            gesture["last"] = (x, y)
            return gui.Widget.EventCallbackResult.CONSUMED
        if kind == gui.MouseEvent.Type.BUTTON_UP:
            self._drag = None
            start = gesture["start"]
            if gesture["mode"] == "pick":
                far = abs(x - start[0]) + abs(y - start[1]) > 3
                self._act(lambda: self.box(start, (x, y)) if far else self.click(x, y))
            elif gesture["mode"] == "brush":
                self._act(lambda: self.brush(gesture["path"]))
            elif not self._flush_posted and gesture["moved"]:  # else the last flush releases
                self.release()
            return gui.Widget.EventCallbackResult.CONSUMED
        return gui.Widget.EventCallbackResult.CONSUMED

    def _flush_drag(self) -> None:
        """Solve once for every drag event received since the last solve (they are coalesced)."""
        self._flush_posted = False
        (dx, dy), self._pending = self._pending, np.zeros(2)
        first = self._drag is not None and not self._drag["moved"]
        if self._drag is not None:
            self._drag["moved"] = True
        self.move(lambda: self.drag(dx, dy, record=first or self._drag is None), live=True)

    def move(self, action: Callable[[], str], blocking: bool = False, live: bool = False) -> None:
        """Apply a move of the active handle, re-pose the mesh (warm-started; ``live``, a mouse drag's move: as the
        backend shows a drag, :meth:`EditorState.preview_drag`) and redraw it; the time from the move to the updated
        scene goes to the status line. Outside a drag (its end, a key, numbers) the move is then settled and the mesh
        shown (:meth:`release`; ``blocking``: before returning)."""
        start = time.perf_counter()
        try:
            message = action()
            if live:
                self.state.preview_drag()
            else:
                self.state.preview()
        except NerfEditError as exc:
            self.say(str(exc), error=True)
            return
        self.update_deformed()
        self.last_update_ms = 1e3 * (time.perf_counter() - start)
        iterations = self.state.backend.last_iterations
        counted = f", {iterations} iteration(s)" if iterations is not None else ""
        self.say(f"{message} · {self.last_update_ms:.0f} ms{counted}")
        if self._drag is None:
            self.release(blocking)

    def release(self, blocking: bool = False) -> None:
        """Settle on release: finish the preview's solve in a worker thread (``blocking``: here) and show it — only if
        the handles did not change meanwhile (the next move cancels it) — with the energy gap closed."""
        snapshot, start = self.state.current, time.perf_counter()

        def wanted() -> bool:
            return self.state.current is snapshot and self._drag is None

        def show(done) -> None:
            if not wanted():
                return
            try:
                self.state.released(done)
            except NerfEditError as exc:
                self.say(str(exc), error=True)
                return
            self.update_deformed(normals=True)
            if done is not None:
                _, before, after, iterations = done
                self.say(
                    f"settled on release: energy {before:.4g} → {after:.4g} ({(before - after) / after:+.1%} of the"
                    f" converged energy closed, {iterations} iterations, {time.perf_counter() - start:.2f} s)"
                )

        def work() -> None:
            try:
                done = self.state.converge(wanted)
            except NerfEditError as exc:
                message = str(exc)
                self.app.post_to_main_thread(self.window, lambda: self.say(message, error=True))
                return
            if blocking:
                show(done)
            else:
                self.app.post_to_main_thread(self.window, lambda: show(done))

        if blocking:
            work()
        else:
            threading.Thread(target=work, daemon=True).start()

    def _on_key(self, event) -> gui.Widget.EventCallbackResult:
        if event.type != gui.KeyEvent.Type.DOWN:
            return gui.Widget.EventCallbackResult.IGNORED
        step = NUDGE * self.state.mesh.bbox_diagonal
        camera = self.view().camera_to_world[:3, :3]
        right, upward, back = camera[:, 0], camera[:, 1], camera[:, 2]
        key = gui.KeyName
        moves = {
            key.LEFT: -step * right, key.RIGHT: step * right, key.UP: step * upward, key.DOWN: -step * upward,
            key.PAGE_UP: -step * back, key.PAGE_DOWN: step * back,
        }  # fmt: skip
        if event.key in moves:
            self.move(lambda: self.state.translate(moves[event.key]))
        elif event.key in (key.Q, key.E):
            self.move(lambda: self.state.rotate(back, 5.0 if event.key == key.Q else -5.0))
        elif event.key in (key.PLUS, key.EQUALS, key.MINUS):
            self.move(lambda: self.state.scale(1.0 / 1.05 if event.key == key.MINUS else 1.05))
        else:
            actions = {
                key.F: lambda: self.state.mark(True), key.M: lambda: self.state.mark(False), key.G: self._grow,
                key.ESCAPE: self.state.clear_selection, key.Z: self.state.undo, key.Y: self.state.redo,
                key.ENTER: self.settle, key.R: self.render, key.S: lambda: self.save(self.spec_path.text_value),
            }  # fmt: skip
            if event.key not in actions:
                return gui.Widget.EventCallbackResult.IGNORED
            self._act(actions[event.key])
        return gui.Widget.EventCallbackResult.CONSUMED

    # ---- scripts -----------------------------------------------------------------------------------
    def _tick(self) -> bool:
        """Run the next script step once the window has drawn a few frames and the last step is done."""
        self._ticks += 1
        if not self.script or self._busy or self._ticks < SCRIPT_WARMUP_TICKS:
            return False
        step = self.script.pop(0)
        if "screenshot" in step:
            self._busy = True
            self.screenshot(step["screenshot"], lambda: setattr(self, "_busy", False))
        elif "quit" in step:
            self._exit()
        elif "drag" in step:
            self.move(lambda: self.drag(*step["drag"]), blocking=True)
        elif any(k in step for k in ("translate", "rotate", "scale")):
            self.move(lambda: self._scripted_move(step), blocking=True)
        else:
            self._act(lambda: self._scripted(step))
        return True

    def _scripted_move(self, step: dict) -> str:
        if "translate" in step:
            return self.state.translate(step["translate"])
        if "rotate" in step:
            rotate = step["rotate"]
            return self.state.rotate(rotate["axis"], rotate["degrees"], rotate.get("pivot"))
        return self.state.scale(step["scale"])

    def _scripted(self, step: dict) -> str | None:
        kind = next((key for key in step if key in SCRIPT_STEPS), None)
        value = step.get(kind)
        actions = {
            "pick": lambda: self.state.select(value),
            "click": lambda: self.click(*value),
            "box": lambda: self.box(value[:2], value[2:]),
            "brush": lambda: self.brush(value, step.get("radius", BRUSH_RADIUS)),
            "grow": lambda: self.state.grow(float(value)),
            "mark": lambda: self.state.mark(value == "fixed"),
            "undo": self.state.undo,
            "redo": self.state.redo,
            "settle": self.settle,
            "render": self.render,
            "save": lambda: self.save(value),
            "frame": lambda: self._set_frame(int(value)),
            "frames": lambda: self._set_frames(int(value)),
            "layer": lambda: "; ".join(self.set_layer(name, on) for name, on in value.items()),
        }
        if kind not in actions:
            raise NerfEditError(f"script: unknown step {json.dumps(step)}")
        return actions[kind]()


SCRIPT_STEPS = (
    "pick", "click", "box", "brush", "grow", "mark", "drag", "translate", "rotate", "scale", "undo", "redo", "settle",
    "render", "save", "screenshot", "layer", "frame", "frames", "quit",
)  # fmt: skip
"""The kinds of script step (the module docstring); ``brush`` may also give a ``radius``."""


def check_script(steps: list[dict], where: str) -> None:
    """A :class:`NerfEditError` naming ``where`` and the step for the first step of no known kind."""
    for i, step in enumerate(steps):
        kinds = [key for key in step if key in SCRIPT_STEPS]
        extra = set(step) - set(kinds[:1]) - ({"radius"} if kinds == ["brush"] else set())
        if len(kinds) != 1 or extra:
            raise NerfEditError(
                f"{where}: step {i} {json.dumps(step)}: unknown step (expected one of {', '.join(SCRIPT_STEPS)})"
            )


class ShownMesh:
    """The tensor meshes of the deformed layer: :attr:`mesh` over the rest ``faces`` and, while the state shows a
    live view (:attr:`EditorState.live`), one over the view's faces (made at its first move, kept while its faces
    are the same array). :meth:`update` is what a move costs the scene: the shown mesh's positions set."""

    def __init__(self, faces: np.ndarray, color=(0.72, 0.74, 0.8)) -> None:
        self.faces, self.color = faces, color
        self.mesh: o3d.t.geometry.TriangleMesh | None = None
        self._live: tuple[np.ndarray, o3d.t.geometry.TriangleMesh] | None = None

    def update(self, state: EditorState, normals: bool) -> o3d.t.geometry.TriangleMesh:
        """The tensor mesh to show for ``state``, its positions set to the live view's vertices or to
        :attr:`EditorState.deformed` (normals recomputed with ``normals``; a mesh made here has them)."""
        live = state.live
        if live is not None:
            if self._live is not None and self._live[0] is live.faces:
                _set_positions(self._live[1], live.vertices, normals)
            else:
                self._live = (live.faces, _mesh(live.vertices, live.faces, self.color))
            return self._live[1]
        if self.mesh is None:
            self.mesh = _mesh(state.deformed, self.faces, self.color)
        else:
            _set_positions(self.mesh, state.deformed, normals)
        return self.mesh


def _mesh(vertices: np.ndarray, faces: np.ndarray, color) -> o3d.t.geometry.TriangleMesh:
    """A tensor triangle mesh with vertex normals, one colour (the legacy mesh stalls Filament under llvmpipe)."""
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.int32))
    mesh.vertex.colors = o3d.core.Tensor(np.tile(np.asarray(color, dtype=np.float32), (len(vertices), 1)))
    _set_positions(mesh, vertices, normals=True)
    return mesh


def _set_positions(mesh: o3d.t.geometry.TriangleMesh, vertices: np.ndarray, normals: bool) -> None:
    """Set ``mesh``'s vertex positions (V,3) in place, and recompute its vertex normals when ``normals``. The positions
    are rounded once into a new float32 array, which the tensor takes over without a copy."""
    mesh.vertex.positions = o3d.core.Tensor.from_numpy(np.array(vertices, dtype=np.float32, order="C"))
    if normals:
        mesh.compute_vertex_normals()


def _points(vertices: np.ndarray, parts) -> o3d.t.geometry.PointCloud:
    """Points of ``vertices`` for each ``(indices, colour)`` part."""
    cloud = o3d.t.geometry.PointCloud(
        o3d.core.Tensor(np.concatenate([vertices[i] for i, _ in parts]).astype(np.float32))
    )
    cloud.point.colors = o3d.core.Tensor(np.concatenate([np.tile(c, (len(i), 1)) for i, c in parts]).astype(np.float32))
    return cloud


def run_editor(state: EditorState, **options) -> None:
    """Open the editor window on ``state`` and run until it is closed (needs a display; ``options``: those of
    :class:`Editor`)."""
    ensure_runtime_dir()
    app = gui.Application.instance
    app.initialize()
    Editor(state, **options)
    app.run()
