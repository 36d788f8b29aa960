"""``nerfedit render``: a run's field, edited or not, from the cameras of a transforms file or along a trajectory."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console, recorded
from nerfedit_plugin.errors import NerfEditError, OptionError, check_option


@dataclasses.dataclass
class RenderArgs:
    """Render a run's field — edited when --deformation is given — from a transforms file's cameras, or animated."""

    run: Path
    """Run folder (`nerfedit train --out`)."""
    out: Path
    """Folder to write: `views` — one PNG per camera (named like the transforms file's frames), in OUT/frame_NNNN/
    per deformation frame when there are several; other trajectories — OUT/frame_NNNN.png per frame (+ videos)."""
    cameras: Path | None = None
    """Transforms JSON (Blender or nerfstudio) or dataset folder (its test split); for --trajectory path also a
    nerfstudio camera_path.json. Not needed for --trajectory orbit."""
    deformation: Path | None = None
    """deformation.npz of an edit (`nerfedit edit --out EDIT_DIR`); default: render the unedited field."""
    frame: str | None = None
    """Frames of the deformation: N, A:B or A:B:STEP (B exclusive; ends may be left out) or all (the default)."""
    trajectory: Literal["views", "fixed", "orbit", "path"] = "views"
    """views: every camera of --cameras for each frame; fixed: camera --view for every frame; orbit: one turn
    around the scene (at the training cameras' distance, elevation and field of view) over the frames; path:
    camera i of --cameras (or of a camera_path.json) for the i-th frame."""
    view: int = 0
    """Camera of --cameras used by --trajectory fixed."""
    size: int = 200
    """Image width and height of --trajectory orbit."""
    shots: int | None = None
    """Images of --trajectory orbit: one turn in SHOTS images, the frames spread evenly over them (default: one per
    frame; 60 when a single frame is rendered, e.g. a still edit)."""
    video: tuple[Literal["mp4", "gif"], ...] = ()
    """Also write OUT/animation.mp4 and/or .gif of the frames (not for --trajectory views)."""
    fps: float | None = None
    """Frames per second of the videos (default: the camera path's, else 24)."""
    supersample: int = 1
    """Anti-aliasing: supersample × supersample rays per pixel, averaged."""
    resume: bool = False
    """Continue an interrupted (partial) render of the same settings, rendering only the missing frames."""
    executor: Literal["local", "ray"] = "local"
    """Where frames are rendered: in this process, or on Ray actors (pip install "nerfedit[ray]"; not --trajectory
    views)."""
    ray_address: str | None = None
    """Ray cluster to join (default: start a local one)."""
    workers: int | None = None
    """Ray actors (default: the cluster's CPUs ÷ torch threads)."""
    overwrite: bool = False
    """Replace an existing image folder."""
    frame_of_cameras: Literal["world", "capture"] = "world"
    """capture: the cameras of --cameras are in the capture's own coordinates (a camera path or transforms file made
    there, e.g. in Blender next to the COLMAP points; not a capture folder, which nerfedit normalises itself): they
    are mapped by the run's capture-to-world similarity."""
    downscale: int = 1
    """Render the cameras of --cameras (or the trajectory) at their size divided by this integer."""

    def __post_init__(self) -> None:
        check_option(self, "downscale", self.downscale, self.downscale >= 1, "a positive integer")
        check_option(self, "supersample", self.supersample, self.supersample >= 1, "a positive integer")
        check_option(self, "view", self.view, self.view >= 0, ">= 0")
        check_option(self, "size", self.size, self.size >= 1, "a positive integer")
        if self.shots is not None:
            check_option(self, "shots", self.shots, self.shots >= 1, "a positive integer")
            if self.trajectory != "orbit":
                raise OptionError(self, "shots", f"only for --trajectory orbit, not {self.trajectory}")
        if self.fps is not None:
            check_option(self, "fps", self.fps, 0 < self.fps < float("inf"), "a positive number")
        if self.workers is not None:
            check_option(self, "workers", self.workers, self.workers >= 1, "a positive integer")
        from nerfedit_plugin.render.animation import parse_frames

        parse_frames(self.frame, None)  # the syntax, before any work


def render(args: RenderArgs) -> None:
    from nerfedit_plugin.pipeline.render import render_run, render_trajectory
    from nerfedit_plugin.pipeline.run import open_run

    run = open_run(args.run)
    if args.trajectory == "views":
        if args.cameras is None:
            raise NerfEditError("--cameras: needed by --trajectory views (a transforms file or dataset folder)")
        for given, flag in ((args.video, "--video"), (args.executor != "local", "--executor ray")):
            if given:
                raise NerfEditError(f"{flag}: for animations (--trajectory fixed, orbit or path), not views")
        out = render_run(
            run, args.cameras, args.deformation, args.frame, args.out, args.overwrite, args.supersample,
            recorded(args), args.resume, args.frame_of_cameras, args.downscale,
        )  # fmt: skip
        console.print(f"renders → {out}")
        return
    out, shots = render_trajectory(
        run, args.trajectory, args.out, deformation=args.deformation, frames=args.frame, cameras=args.cameras,
        view=args.view, size=args.size, shots=args.shots, supersample=args.supersample,
        frame_of_cameras=args.frame_of_cameras, downscale=args.downscale, videos=args.video, fps=args.fps,
        executor=args.executor, ray_address=args.ray_address, workers=args.workers, overwrite=args.overwrite,
        resume=args.resume, record=recorded(args),
    )  # fmt: skip
    console.print(f"{shots} {'shots' if args.trajectory == 'orbit' else 'frames'} → {out}")


COMMAND = Command("render", RenderArgs, render, records=True)
