"""Open3D viewer of an edit: rest and deformed mesh, tet proxy, handles, the deformer's overlays — windowed or headless.

An edit folder (``nerfedit edit --out EDIT_DIR``) supplies the deformed mesh, ``deformation.npz`` (rest and
deformed proxy) and the spec's handles; its deformer adds what it wrote (``Deformer.overlays``).
Deformed geometry is shifted along +x by ``1.2 ×`` the rest bounding box width so rest and edit sit side by side.
Windows need a display (``draw_geometries``); :func:`screenshot` renders offscreen with the legacy
``Visualizer(visible=False)`` (EGL when no display is present) and writes a PNG.
"""

from __future__ import annotations

import atexit
import os
import shutil
import stat
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import yaml

from nerfedit_plugin.bending.scene_deformation import SceneDeformation
from nerfedit_plugin.data.datasets import to_uint8
from nerfedit_plugin.edit.deformer import Deformer
from nerfedit_plugin.edit.objects import is_objects_spec
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_path
from nerfedit_plugin.registry import DEFORMERS, discover

LAYERS = ("mesh", "deformed", "proxy", "deformed-proxy", "handles")
DEFAULT_LAYERS = ("mesh", "deformed", "deformed-proxy", "handles")
"""Shown when no layers are named, with every overlay of the edit's deformer."""
DEFAULT_FRONT = (0.3, 0.2, 1.0)
"""Direction towards the camera of a screenshot of a y-up scene (slightly right of and above the front)."""
FIXED, MOVED, OVERLAY = (0.15, 0.35, 0.95), (0.95, 0.2, 0.15), (0.2, 0.6, 0.3)


def _triangles(mesh: SurfaceMesh, color: Sequence[float] | None = None):
    out = mesh.to_open3d()
    out.compute_vertex_normals()
    if color is not None or mesh.vertex_colors is None:
        out.paint_uniform_color(color or (0.75, 0.75, 0.72))
    return out


def _edges(vertices: np.ndarray, tets_or_faces: np.ndarray, color: Sequence[float]):
    """LineSet of the unique edges of tets ``(K,4)`` or triangles ``(F,3)``."""
    import open3d as o3d

    k = tets_or_faces.shape[1]
    pairs = np.concatenate([tets_or_faces[:, [i, j]] for i in range(k) for j in range(i + 1, k)])
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    lines = o3d.geometry.LineSet(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector2iVector(pairs))
    lines.paint_uniform_color(color)
    return lines


def _handles(spec_path: Path, deformer: type[Deformer], points_of_handles: np.ndarray):
    """Point cloud of the spec's handle selections on ``points_of_handles`` (what the deformer's handles grab), fixed
    blue, moved red; None when the spec has no handles."""
    import open3d as o3d

    spec = load_edit_spec(spec_path, deformer.spec_keys)
    if not spec.handles:
        return None
    points, colors = [], []
    for handle in spec.handles:
        idx = handle.selection.indices(points_of_handles, spec.source)
        points.append(points_of_handles[idx])
        colors.append(np.tile(FIXED if handle.transform is None else MOVED, (len(idx), 1)))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(points)))
    cloud.colors = o3d.utility.Vector3dVector(np.concatenate(colors))
    return cloud


def _overlay(mesh: SurfaceMesh | None, style: str, shift: np.ndarray):
    if mesh is None:
        return []
    moved = mesh.with_vertices(mesh.vertices + shift)
    if style == "wire":
        return [_edges(moved.vertices, moved.faces, OVERLAY)]
    return [_triangles(moved, OVERLAY if mesh.vertex_colors is None else None)]  # keep a coloured overlay's colours


def edit_geometries(
    mesh: SurfaceMesh, edit_dir: str | os.PathLike | None = None, frame: int = 0, layers: Iterable[str] | None = None
) -> list:
    """The Open3D geometries of ``layers`` for a rest ``mesh`` and an optional edit folder. Built-in layers are
    :data:`LAYERS`; the edit's deformer adds its own (:meth:`Deformer.overlays`). ``None``:
    :data:`DEFAULT_LAYERS` and every overlay. Layers the folder does not hold are left out."""
    given = layers is not None
    layers = set(layers) if given else set(DEFAULT_LAYERS)
    shift = _beside(mesh)
    out = [_triangles(mesh)] if "mesh" in layers else []
    if edit_dir is None:
        _check_layers(layers, LAYERS)
        return out
    edit_dir = Path(edit_dir)
    config_file = edit_dir / "config.yml"
    if not config_file.is_file():
        raise NerfEditError(f"{edit_dir}: not an edit folder (no config.yml; make one with `nerfedit edit`)")
    record = yaml.safe_load(config_file.read_text()) or {}
    name = record.get("deformer")  # without one: the contract's defaults (no overlays, handles on the rest vertices)
    deformer = Deformer if name is None else discover(DEFORMERS).config_class(DEFORMERS, str(name))()._target
    meshes = sorted(edit_dir.glob("deformed_mesh*.ply"))
    if not 0 <= frame < len(meshes):
        raise NerfEditError(f"frame: {frame} out of range for the {len(meshes)} deformed mesh(es) in {edit_dir}")
    overlays = deformer.overlays(edit_dir, frame)
    layers |= set() if given else {o.layer for o in overlays}
    _check_layers(layers, LAYERS + tuple(o.layer for o in overlays))
    if "deformed" in layers:
        deformed = SurfaceMesh.load(meshes[frame])
        out.append(_triangles(deformed.with_vertices(deformed.vertices + shift)))
    if layers & {"proxy", "deformed-proxy"} and (edit_dir / "deformation.npz").is_file():
        for _, rest, tets, deformed in SceneDeformation.load(edit_dir / "deformation.npz").proxies(frame):
            if "proxy" in layers:
                out.append(_edges(rest, tets, (0.55, 0.55, 0.6)))
            if "deformed-proxy" in layers:
                out.append(_edges(deformed + shift, tets, (0.9, 0.55, 0.2)))
    for overlay in (o for o in overlays if o.layer in layers):
        out += _overlay(overlay.rest, overlay.style, np.zeros(3)) + _overlay(overlay.deformed, overlay.style, shift)
    spec = Path(str(record.get("edit", ""))).name
    if "handles" in layers and spec and (edit_dir / spec).is_file() and not is_objects_spec(edit_dir / spec):
        handles = _handles(edit_dir / spec, deformer, deformer.handle_points(edit_dir, mesh))
        out += [handles] if handles is not None else []
    return out


def settled_geometries(mesh: SurfaceMesh, deformed: SurfaceMesh | None, layers: Iterable[str] | None = None) -> list:
    """The editor's state as the ``mesh`` and ``deformed`` layers: the rest ``mesh`` and, beside it as in
    :func:`edit_geometries`, its ``deformed`` copy (None: the rest mesh alone). ``None`` layers: both."""
    layers = set(layers) if layers is not None else {"mesh", "deformed"}
    _check_layers(layers, ("mesh", "deformed"))
    out = [_triangles(mesh)] if "mesh" in layers else []
    if deformed is not None and "deformed" in layers:
        out.append(_triangles(deformed.with_vertices(deformed.vertices + _beside(mesh))))
    return out


def _beside(mesh: SurfaceMesh) -> np.ndarray:
    """The shift that shows a deformed copy beside the rest ``mesh`` (along x, 1.2 × its width)."""
    return np.array([1.2 * float(np.ptp(mesh.vertices[:, 0])), 0.0, 0.0])


def _check_layers(layers: set[str], known: tuple[str, ...]) -> None:
    unknown = layers - set(known)
    if unknown:
        raise NerfEditError(f"show: unknown layer(s) {', '.join(sorted(unknown))} (choose from {', '.join(known)})")


def screenshot(
    geometries: list,
    path: str | os.PathLike,
    width: int = 960,
    height: int = 540,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    front: Sequence[float] | None = None,
) -> Path:
    """Render ``geometries`` offscreen (no display needed) and write the PNG atomically. ``up`` is the world's up
    direction; ``front`` (towards the camera) defaults to :data:`DEFAULT_FRONT` turned with the rotation taking +y
    to ``up`` (the same view of a y-up mesh and of its z-up copy in a `nerfedit generate` dataset)."""
    if not geometries:
        raise NerfEditError("show: nothing to draw")
    up = _unit(up, "up")
    front = _rotate_y_to(up, DEFAULT_FRONT) if front is None else _unit(front, "front")
    ensure_runtime_dir()
    import open3d as o3d

    vis = o3d.visualization.Visualizer()
    verbosity = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # GLFW's "no platform", EGL's fallback notes
    try:
        created = vis.create_window(visible=False, width=width, height=height)
    finally:
        o3d.utility.set_verbosity_level(verbosity)
    if not created:
        raise NerfEditError("screenshot: Open3D could not create an offscreen window (no display and no EGL)")
    try:
        for geometry in geometries:
            vis.add_geometry(geometry)
        view = vis.get_view_control()
        view.set_up(up.tolist())
        view.set_front(front.tolist())
        view.set_zoom(0.7)
        vis.get_render_option().point_size = 6.0
        vis.poll_events()
        vis.update_renderer()
        image = np.asarray(vis.capture_screen_float_buffer(do_render=True))
    finally:
        vis.destroy_window()
    import skimage.io

    with atomic_path(path) as tmp:
        skimage.io.imsave(tmp, to_uint8(image), check_contrast=False)
    return Path(path)


def _unit(vector: Sequence[float], name: str) -> np.ndarray:
    v = np.asarray(vector, dtype=np.float64)
    norm = float(np.linalg.norm(v)) if v.shape == (3,) else 0.0
    if not (np.isfinite(norm) and norm > 0):
        raise NerfEditError(f"{name}: expected a non-zero direction (3 finite numbers), got {tuple(np.ravel(v))}")
    return v / norm


def _rotate_y_to(up: np.ndarray, vector: Sequence[float]) -> np.ndarray:
    """``vector`` turned by the shortest rotation taking +y to the unit vector ``up`` (Rodrigues)."""
    v, y = np.asarray(vector, dtype=np.float64), np.array([0.0, 1.0, 0.0])
    axis, cos = np.cross(y, up), float(y @ up)
    if np.linalg.norm(axis) < 1e-12:
        return v if cos > 0 else v * np.array([1.0, -1.0, -1.0])  # +y or -y: identity or half turn about x
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rotation = np.eye(3) + k + k @ k / (1.0 + cos)
    return rotation @ v


def ensure_runtime_dir() -> None:
    """Point ``XDG_RUNTIME_DIR`` at a private folder when it is unset or unusable, before Open3D starts: EGL/Mesa
    otherwise print ``error: XDG_RUNTIME_DIR is invalid or not set`` (a warning of theirs, not an error of ours) on
    every headless screenshot. A valid setting is left alone; the folder made here is removed at exit."""
    current = os.environ.get("XDG_RUNTIME_DIR")
    if current:
        try:
            info = os.stat(current)
            if stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and stat.S_IMODE(info.st_mode) & 0o077 == 0:
                return
        except OSError:
            pass
    folder = tempfile.mkdtemp(prefix="nerfedit-runtime-")  # mode 0700, owned by this user
    atexit.register(shutil.rmtree, folder, True)
    os.environ["XDG_RUNTIME_DIR"] = folder


def show(geometries: list, title: str = "nerfedit") -> None:
    """Open an interactive Open3D window (needs a display)."""
    import open3d as o3d

    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise NerfEditError("view: no display (set DISPLAY, or pass --screenshot PNG to render offscreen)")
    o3d.visualization.draw_geometries(geometries, window_name=title)
