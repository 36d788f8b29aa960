"""``nerfedit extract``: a run's surface mesh into RUN_DIR/mesh.ply, optionally cleaned of a scene's floor and
floaters."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console
from nerfedit_plugin.errors import NerfEditError, check_option


@dataclasses.dataclass
class ExtractArgs:
    """Extract the run's surface mesh (marching cubes) into RUN_DIR/mesh.ply; a mesh field's run has it already."""

    run: Path
    """Run folder (`nerfedit train --out`)."""
    resolution: int = 256
    """Marching-cubes lattice points per axis over the scene box."""
    level: float | None = None
    """Density (nerf) or SDF (neus) level of the surface; default: the backend's."""
    largest_component: bool = True
    """Keep only the largest connected part (drops floaters, which no deformer handle would reach); replaced by
    --drop-floaters when that is given."""
    drop_plane: bool = False
    """Remove the vertices on the mesh's largest plane (a scene's floor), so objects standing on it come apart."""
    drop_floaters: float | None = None
    """Keep every connected part of at least this fraction of the largest part's faces (after --drop-plane),
    instead of the largest part only: the objects of a scene without its floaters."""
    overwrite: bool = False
    """Replace an existing mesh.ply (a mesh field's own mesh.ply is kept without it: it is the field)."""
    frame: Literal["world", "capture"] = "world"
    """capture: also write RUN_DIR/mesh_capture.ply, the mesh in the capture's own coordinates (e.g. next to the
    COLMAP points); mesh.ply stays in the run's frame, the one edits use."""

    def __post_init__(self) -> None:
        check_option(self, "resolution", self.resolution, self.resolution >= 2, "an integer >= 2")
        if self.level is not None:
            check_option(self, "level", self.level, math.isfinite(self.level), "a finite number")
        if self.drop_floaters is not None:
            check_option(self, "drop_floaters", self.drop_floaters, 0 <= self.drop_floaters <= 1, "in [0, 1]")


def extract(args: ExtractArgs) -> None:
    from nerfedit_plugin.geometry.cleanup import drop_floaters, drop_plane
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.io.run import export_capture_mesh, extract_mesh, open_run

    run = open_run(args.run)
    clean = args.drop_plane or args.drop_floaters is not None
    if clean and run.from_mesh:
        raise NerfEditError(
            f"{run.path}: the mesh field's mesh is its field and stays whole: clean the mesh before "
            "`nerfedit train --field mesh` (--drop-plane, --drop-floaters)"
        )
    largest = args.largest_component and args.drop_floaters is None

    def cleaned(mesh: SurfaceMesh) -> SurfaceMesh:
        if args.drop_plane:
            mesh = drop_plane(mesh)
        if args.drop_floaters is not None:
            mesh = drop_floaters(mesh, args.drop_floaters)
        if not len(mesh.faces):
            raise NerfEditError(f"{run.mesh_path}: nothing is left after the clean-up (--drop-plane, --drop-floaters)")
        return mesh

    path = extract_mesh(
        run,
        args.resolution,
        args.level,
        overwrite=args.overwrite,
        largest_component=largest,
        clean=cleaned if clean else None,
    )
    mesh = run.mesh()
    own = " (the mesh field's own mesh)" if run.from_mesh else ""
    console.print(f"{path}: {mesh.n_vertices} vertices, {len(mesh.faces)} faces{own}")
    if args.frame == "capture":
        console.print(f"capture frame → {export_capture_mesh(run, overwrite=args.overwrite)}")


COMMAND = Command("extract", ExtractArgs, extract)
