"""``nerfedit view``: a mesh and an edit in Open3D (a window, or an offscreen screenshot)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nerfedit_plugin.cli.common import CONFIG, Command, console
from nerfedit_plugin.errors import NerfEditError


@dataclasses.dataclass
class ViewArgs:
    """Show a mesh and an edit (deformed mesh, tet proxies, cages, handles) with Open3D; headless: --screenshot."""

    mesh: str | None = None
    """Rest mesh, or sample:NAME; default: the mesh the edit folder's config names."""
    edit: Path | None = None
    """Edit folder (`nerfedit edit --out`)."""
    frame: int = 0
    """Frame of an animated edit."""
    show: tuple[str, ...] | None = None
    """Layers: mesh, deformed, proxy, deformed-proxy, handles, and what the edit's deformer adds (cage); default:
    all but proxy."""
    screenshot: Path | None = None
    """Render offscreen into this PNG instead of opening a window (works without a display)."""
    width: int = 960
    """Screenshot width in pixels."""
    height: int = 540
    """Screenshot height in pixels."""
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    """World up direction of the view (samples: y; datasets of `nerfedit generate`: z)."""


def view(args: ViewArgs) -> None:
    import yaml

    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.viewer.layers import edit_geometries, screenshot, show

    mesh = args.mesh
    if mesh is None and args.edit is not None and (args.edit / CONFIG).is_file():
        mesh = (yaml.safe_load((args.edit / CONFIG).read_text()) or {}).get("mesh")
    if mesh is None:
        raise NerfEditError("view: give --mesh MESH (the edit folder's config names no mesh)")
    geometries = edit_geometries(SurfaceMesh.load(mesh), args.edit, args.frame, args.show)
    if args.screenshot is not None:
        console.print(f"screenshot → {screenshot(geometries, args.screenshot, args.width, args.height, args.up)}")
    else:
        show(geometries)


COMMAND = Command("view", ViewArgs, view)
