"""``nerfedit render``: a run's field, edited or not, from the cameras of a transforms file."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from nerfedit_plugin.cli.common import CONFIG, Command, console, recorded
from nerfedit_plugin.errors import check_option


@dataclasses.dataclass
class RenderArgs:
    """Render a run's field — edited when --deformation is given — from the cameras of a transforms file."""

    run: Path
    """Run folder (`nerfedit train --out`)."""
    cameras: Path
    """Transforms JSON (Blender or nerfstudio) or dataset folder (its test split) with the cameras to render."""
    out: Path
    """Image folder to write (one PNG per camera, named like the transforms file's frames; and config.yml)."""
    deformation: Path | None = None
    """deformation.npz of an edit (`nerfedit edit --out EDIT_DIR`); default: render the unedited field."""
    frame: int | None = None
    """Frame of an animated deformation (default: every frame, into OUT/frame_0000, ...)."""
    supersample: int = 1
    """Anti-aliasing: supersample × supersample rays per pixel, averaged."""
    overwrite: bool = False
    """Replace an existing image folder."""

    def __post_init__(self) -> None:
        check_option(self, "supersample", self.supersample, self.supersample >= 1, "a positive integer")
        if self.frame is not None:
            check_option(self, "frame", self.frame, self.frame >= 0, ">= 0")


def render_run(
    run,
    cameras: Path,
    deformation: Path | None,
    frame: int | None,
    out: Path,
    overwrite: bool,
    supersample: int = 1,
    record: Any = None,
) -> Path:
    """Render ``run``'s field from a transforms file (bent by ``deformation``: one frame, or every frame into
    ``out/frame_NNNN``) into PNGs named like the file's frames, atomically; ``record`` goes to ``out/config.yml``."""
    from nerfedit_plugin.bending.deformation_field import DeformationField
    from nerfedit_plugin.config import write_config
    from nerfedit_plugin.data.datasets import read_transforms
    from nerfedit_plugin.io.atomic import atomic_dir
    from nerfedit_plugin.io.faults import fault_point
    from nerfedit_plugin.render.views import default_render_config, render_views, write_images

    field = run.field()
    transforms = read_transforms(cameras, "test" if Path(cameras).is_dir() else None)
    names = [p.with_suffix(".png").name for p in transforms.image_paths]
    bent = DeformationField.load(deformation) if deformation is not None else None
    config = default_render_config(field)
    frames = [frame or 0] if bent is None or frame is not None or bent.n_frames == 1 else range(bent.n_frames)
    with atomic_dir(out, overwrite) as stage:
        for f in frames:
            images = render_views(field, transforms.cameras, config, deformation=bent, frame=f, supersample=supersample)
            write_images(images, names, stage if len(frames) == 1 else stage / f"frame_{f:04d}")
            fault_point("render.frame")
        if record is not None:
            write_config(stage / CONFIG, record)
    return Path(out)


def render(args: RenderArgs) -> None:
    from nerfedit_plugin.io.run import open_run

    out = render_run(
        open_run(args.run),
        args.cameras,
        args.deformation,
        args.frame,
        args.out,
        args.overwrite,
        args.supersample,
        record=recorded(args),
    )
    console.print(f"renders → {out}")


COMMAND = Command("render", RenderArgs, render, records=True)
