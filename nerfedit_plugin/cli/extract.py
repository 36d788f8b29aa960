"""``nerfedit extract``: a run's surface mesh into RUN_DIR/mesh.ply, optionally cleaned of a scene's floor and
floaters."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console
from nerfedit_plugin.errors import check_option


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
    from nerfedit_plugin.pipeline.extract import export_capture_mesh, extract_mesh
    from nerfedit_plugin.pipeline.run import open_run

    run = open_run(args.run)
    path = extract_mesh(
        run,
        args.resolution,
        args.level,
        largest_component=args.largest_component,
        drop_plane=args.drop_plane,
        drop_floaters=args.drop_floaters,
        overwrite=args.overwrite,
    )
    mesh = run.mesh()
    own = " (the mesh field's own mesh)" if run.exact_mesh else ""
    console.print(f"{path}: {mesh.n_vertices} vertices, {len(mesh.faces)} faces{own}")
    if args.frame == "capture":
        console.print(f"capture frame → {export_capture_mesh(run, overwrite=args.overwrite)}")


COMMAND = Command("extract", ExtractArgs, extract)
