"""``nerfedit train``: train a field backend (or build the mesh field) into a run folder."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, print_table, recorded
from nerfedit_plugin.errors import check_option
from nerfedit_plugin.registry import FIELDS


@dataclasses.dataclass
class TrainArgs:
    """Train a field backend on a dataset (or, for the mesh field, load a vertex-coloured mesh) into a run folder."""

    data: Path
    """Dataset folder or transforms JSON (Blender or nerfstudio), or a COLMAP workspace (images/ + sparse/0/); a mesh
    file for --field mesh."""
    out: Path
    """Run folder to write (field.pt, config.yml, log.json; mesh.ply for the mesh field)."""
    field: str = "nerf"
    """Field backend (entry point group nerfedit.fields; listed above, and by `nerfedit plugins`)."""
    device: str | None = None
    """torch device (default: cuda when present, else cpu)."""
    overwrite: bool = False
    """Replace an existing run folder (only after the new one is complete)."""
    downscale: int = 1
    """Train on the images downscaled by this integer factor (block averaging; cached with undistorted frames)."""
    scene_box: tuple[float, float, float, float, float, float] | None = None
    """The field's box, min x y z then max x y z (default: the dataset's aabb, a capture's foreground box from its
    sparse points or camera frustums); the mesh is extracted inside it."""
    frame: Literal["world", "capture"] = "world"
    """Frame of --scene-box: the run's (normalised) world, or the capture's own coordinates (e.g. COLMAP's)."""
    dataparser_transforms: Path | None = None
    """With a model file: nerfstudio's dataparser_transforms.json of the run it was exported from (ns-export keeps
    the Gaussians in nerfstudio's normalised frame); recorded as the run's capture frame, so cameras in the dataset's
    coordinates render through `render --frame-of-cameras capture`, and `extract --frame capture` maps back."""

    def __post_init__(self) -> None:
        check_option(self, "downscale", self.downscale, self.downscale >= 1, "a positive integer")


def train(args: TrainArgs) -> None:
    from nerfedit_plugin.pipeline.train import train_run

    run, log = train_run(
        args.field,
        args.field_options,
        args.data,
        args.out,
        overwrite=args.overwrite,
        device=args.device,
        record=recorded(args),
        downscale=args.downscale,
        scene_box=args.scene_box,
        box_frame=args.frame,
        dataparser=args.dataparser_transforms,
    )
    evals = log.get("eval") or []
    print_table(
        f"nerfedit train → {run.path}",
        ("field", "steps", "seconds", "held-out PSNR"),
        [
            (
                run.backend,
                log.get("steps", 0),
                f"{log.get('train_seconds', 0.0):.1f}",
                f"{evals[-1][1]:.2f} dB" if evals else "—",
            )
        ],
    )


COMMAND = Command("train", TrainArgs, train, plugin=("field", FIELDS, "nerf"), records=True)
