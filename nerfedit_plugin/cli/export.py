"""``nerfedit export``: a splat run's model, edited when --deformation is given, as INRIA PLY or .splat files."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console, recorded


@dataclasses.dataclass
class ExportArgs:
    """Write a splat run's Gaussians (moved by an edit's deformation when given) as INRIA PLY or .splat files.

    One file per frame, opened by other 3DGS tools and by `nerfedit train --field splats --data FILE`."""

    run: Path
    """Run folder of a splats field (`nerfedit train --field splats`)."""
    out: Path
    """Folder to write: point_cloud.ply (or .splat) for one frame, frame_NNNN.ply per frame for several, export.json
    (Gaussians and the forward map's counts per file)."""
    deformation: Path | None = None
    """deformation.npz of an edit (`nerfedit edit --run RUN --out EDIT_DIR`); default: the unedited model."""
    frame: str | None = None
    """Frames of the deformation: N, A:B or A:B:STEP (B exclusive; ends may be left out) or all (the default)."""
    format: Literal["ply", "splat"] = "ply"
    """ply: the INRIA layout (float32, every SH band); splat: antimatter15's 32-byte records (DC colour only)."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""

    def __post_init__(self) -> None:
        from nerfedit_plugin.render.animation import parse_frames

        parse_frames(self.frame, None)  # the syntax, before any work


def export(args: ExportArgs) -> None:
    from nerfedit_plugin.pipeline.export import export_run
    from nerfedit_plugin.pipeline.run import open_run

    def announce(plan) -> None:
        if plan.files > 1:
            console.print(f"writing {plan.files} files of {_size(plan.bytes_per_file)}: {_size(plan.total_bytes)}")

    result = export_run(
        open_run(args.run),
        args.out,
        deformation=args.deformation,
        frames=args.frame,
        format=args.format,
        overwrite=args.overwrite,
        record=recorded(args),
        on_plan=announce,
    )
    for entry in result.report["files"]:
        moved, detail = entry.get("deformation"), ""
        if moved is not None:
            detail = f", {moved['moved']} moved ({moved['inverted']} in inverted tets)"
            for key, what in (("removed", "removed"), ("copied", "copies")):
                detail += f", {moved[key]} {what}" if moved[key] else ""
            detail += f", anisotropy growth up to {moved['growth']['max']:.2f}"
            if moved["split"]:
                detail += f", {moved['split']} split into {moved['split'] + moved['children']}"
        console.print(f"{result.out / entry['file']}: {entry['gaussians']} Gaussians{detail}")


def _size(n: int) -> str:
    return f"{n / 1e9:.2f} GB" if n >= 1e9 else f"{n / 1e6:.1f} MB"


COMMAND = Command("export", ExportArgs, export, records=True)
