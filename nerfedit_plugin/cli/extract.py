"""``nerfedit extract``: a run's surface mesh into RUN_DIR/mesh.ply."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

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
    """Keep only the largest connected part (drops floaters, which no deformer handle would reach)."""
    overwrite: bool = False
    """Replace an existing mesh.ply (a mesh field's own mesh.ply is kept without it: it is the field)."""

    def __post_init__(self) -> None:
        check_option(self, "resolution", self.resolution, self.resolution >= 2, "an integer >= 2")
        if self.level is not None:
            check_option(self, "level", self.level, math.isfinite(self.level), "a finite number")


def extract(args: ExtractArgs) -> None:
    from nerfedit_plugin.io.run import extract_mesh, open_run

    run = open_run(args.run)
    path = extract_mesh(
        run, args.resolution, args.level, overwrite=args.overwrite, largest_component=args.largest_component
    )
    mesh = run.mesh()
    own = " (the mesh field's own mesh)" if run.from_mesh else ""
    console.print(f"{path}: {mesh.n_vertices} vertices, {len(mesh.faces)} faces{own}")


COMMAND = Command("extract", ExtractArgs, extract)
