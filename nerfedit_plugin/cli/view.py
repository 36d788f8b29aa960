"""``nerfedit view``: the interactive editor (``--mesh`` or ``--run``), or an edit in Open3D (``--edit``: a window, or
an offscreen ``--screenshot``)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any

from nerfedit_plugin.cli.common import Command, console
from nerfedit_plugin.errors import NerfEditError, check_option


@dataclasses.dataclass
class ViewArgs:
    """Edit a mesh or a run's field interactively, or show an edit, in an Open3D window. --mesh / --run: pick handles,
    drag, render, save a spec; --edit: the deformed mesh, tet proxies, cages and handles; headless: --screenshot."""

    mesh: str | None = None
    """Rest mesh, or sample:NAME; default: the mesh the edit folder's config names."""
    run: Path | None = None
    """Run folder (`nerfedit train`, then `nerfedit extract`): edit its mesh, render its field (R)."""
    edit: Path | None = None
    """Edit folder (`nerfedit edit --out`)."""
    frame: int = 0
    """Frame of an animated edit."""
    show: tuple[str, ...] | None = None
    """Layers: mesh, deformed, proxy, deformed-proxy, handles, and what the edit's deformer adds (cage); default:
    all but proxy."""
    screenshot: Path | None = None
    """Render offscreen into this PNG instead of opening a window (works without a display): with --edit, the edit's
    layers; with --mesh or --run, the editor's state (the rest mesh, and --spec settled beside it when it exists)."""
    width: int = 960
    """Screenshot width in pixels."""
    height: int = 540
    """Screenshot height in pixels."""
    up: tuple[float, float, float] | None = None
    """World up direction of the view; default: that of the run's dataset, or of the dataset a --mesh file sits in
    (z for datasets of `nerfedit generate`, else their cameras' up), else y (the samples' convention)."""

    spec: Path | None = None
    """Editor: where Save (S) writes the edit spec (selection files beside it; default edit.json); when it exists,
    its handles (and the deformer's files) are loaded to keep editing. With --screenshot: the spec shown settled
    (only when given)."""
    deformer: str = "arap"
    """Editor: arap (handles on mesh vertices), cage (on the cage's vertices), skeleton (joints of --skeleton), or a
    plugin's deformer that declares an editing backend."""
    cage: Path | None = None
    """Editor, --deformer cage: the cage mesh; default: the automatic cage ("cage": "auto")."""
    skeleton: Path | None = None
    """Editor, --deformer skeleton: the skeleton (JSON joints or BVH) whose joints are posed."""
    frames: int = 1
    """Editor: frames of the edit (> 1: an animation from the rest pose, shown with the frame slider)."""
    script: Path | None = None
    """Editor: a JSON list of steps to run without a person (see nerfedit_plugin/viewer/editor.py)."""

    def __post_init__(self) -> None:
        check_option(self, "frames", self.frames, self.frames >= 1, ">= 1")
        check_option(self, "frame", self.frame, self.frame >= 0, ">= 0")
        check_option(self, "width", self.width, self.width >= 1, "a positive number of pixels")
        check_option(self, "height", self.height, self.height >= 1, "a positive number of pixels")
        if self.up is not None:
            ok = all(math.isfinite(c) for c in self.up) and any(c != 0 for c in self.up)
            check_option(self, "up", self.up, ok, "a non-zero direction")


Y_UP = (0.0, 1.0, 0.0)


def _up(args: ViewArgs, run: Any, mesh: str | None) -> tuple[float, float, float]:
    """``--up``, else the up of the run's dataset or of the dataset the mesh file sits in, else y."""
    from nerfedit_plugin.pipeline.run import data_up

    if args.up is not None:
        return args.up
    source = Path(run.data) if run is not None else None
    if source is None and mesh is not None and not mesh.startswith("sample:"):
        source = Path(mesh)
    return (data_up(source) if source is not None else None) or Y_UP


def view(args: ViewArgs) -> None:
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.pipeline.edit import EditFolder
    from nerfedit_plugin.pipeline.run import open_run
    from nerfedit_plugin.viewer.layers import edit_geometries, screenshot, show

    if args.edit is None and args.screenshot is None:
        edit(args)
        return
    if args.edit is None:  # the editor's state, offscreen: the rest mesh, and --spec settled beside it
        from nerfedit_plugin.viewer.editor_state import EditorState
        from nerfedit_plugin.viewer.layers import settled_geometries

        run, rest = _source(args)
        deformed = None
        if args.spec is not None:
            source_to_world = run.source_transform() if run is not None else None
            frames = EditorState.open(args.deformer, rest, args.spec, _keys(args), source_to_world).settled
            if args.frame >= len(frames):
                raise NerfEditError(f"--frame: {args.frame} out of range for the {len(frames)} frame(s) of {args.spec}")
            deformed = rest.with_vertices(frames[args.frame])
        up = _up(args, run, args.mesh)
        path = screenshot(settled_geometries(rest, deformed, args.show), args.screenshot, args.width, args.height, up)
        console.print(f"screenshot → {path}")
        return
    mesh, run = args.mesh, None
    if mesh is None and args.edit is not None:
        folder = EditFolder.open(args.edit)
        mesh = folder.mesh
        if mesh is None and folder.run is not None:
            run = open_run(folder.run)
    if mesh is None and run is None:
        raise NerfEditError("view: give --mesh MESH (or --edit EDIT_DIR of an edit made with --mesh or --run)")
    rest = run.mesh() if run is not None else SurfaceMesh.load(mesh)
    up = _up(args, run, mesh)
    geometries = edit_geometries(rest, args.edit, args.frame, args.show)
    if args.screenshot is not None:
        console.print(f"screenshot → {screenshot(geometries, args.screenshot, args.width, args.height, up)}")
    else:
        show(geometries)


def edit(args: ViewArgs) -> None:
    """Open the editor on ``--mesh`` or ``--run`` (the run's mesh; its field renders the edit)."""
    from nerfedit_plugin.viewer.backends import editing_backend
    from nerfedit_plugin.viewer.editor_state import EditorState

    run, rest = _source(args)
    script = None
    if args.script is not None:
        try:
            script = json.loads(args.script.read_text())
        except (OSError, ValueError) as exc:
            raise NerfEditError(f"{args.script}: cannot read the script ({exc})") from exc
        if not isinstance(script, list) or not all(isinstance(step, dict) and len(step) >= 1 for step in script):
            raise NerfEditError(f'{args.script}: expected a JSON list of steps ({{"pick": [...]}}, ...)')
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise NerfEditError("view: the editor needs a display (set DISPLAY, or run it under xvfb-run)")
    from nerfedit_plugin.viewer.editor import check_script, run_editor
    from nerfedit_plugin.viewer.field_preview import FieldPreview

    if script is not None:
        check_script(script, str(args.script))

    spec = args.spec or Path("edit.json")
    if spec.is_file():
        source_to_world = run.source_transform() if run is not None else None
        state = EditorState.open(args.deformer, rest, spec, _keys(args), source_to_world)
        console.print(f"{spec}: {len(state.handles)} handle(s) loaded")
    else:
        state = EditorState(editing_backend(args.deformer, rest, _keys(args)), frames=args.frames)
    up = _up(args, run, args.mesh)
    preview = FieldPreview(run, rest) if run is not None else None
    run_editor(state, preview=preview, spec_path=spec, up=up, script=script)


def _source(args: ViewArgs) -> tuple[Any, Any]:
    """``(run or None, rest mesh)`` of the editor: ``--mesh``, or ``--run``'s mesh."""
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.pipeline.run import open_run

    if (args.mesh is None) == (args.run is None):
        raise NerfEditError("view: give --mesh MESH or --run RUN to edit (or --edit EDIT_DIR to look at an edit)")
    run = open_run(args.run) if args.run is not None else None
    return run, run.mesh() if run is not None else SurfaceMesh.load(args.mesh)


def _keys(args: ViewArgs) -> dict:
    """The deformer files given on the command line (``--cage``, ``--skeleton``), resolved."""
    return {key: path.resolve() for key, path in (("cage", args.cage), ("skeleton", args.skeleton)) if path}


COMMAND = Command("view", ViewArgs, view)
