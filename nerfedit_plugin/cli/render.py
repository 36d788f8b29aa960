"""``nerfedit render``: a run's field, edited or not, from the cameras of a transforms file or along a trajectory."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from nerfedit_plugin.cli.common import CONFIG, Command, console, recorded
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


def render_run(
    run,
    cameras: Path,
    deformation: Path | None,
    frames: Sequence[int] | None,
    out: Path,
    overwrite: bool,
    supersample: int = 1,
    record: Any = None,
    resume: bool = False,
    frame_of_cameras: str = "world",
    downscale: int = 1,
) -> Path:
    """Render ``run``'s field from every camera of a transforms file (bent by ``deformation`` at each of ``frames``,
    default all: one frame into ``out``, several into ``out/frame_NNNN``) into PNGs named like the file's frames,
    atomically; several frames are kept as a partial output when interrupted, and ``resume`` continues one;
    ``record`` goes to ``out/config.yml``. ``frame_of_cameras`` and ``downscale``: see :func:`run_cameras`."""
    from nerfedit_plugin.bending.scene_deformation import load_deformation
    from nerfedit_plugin.config import write_config
    from nerfedit_plugin.data.datasets import read_transforms
    from nerfedit_plugin.io.atomic import atomic_dir, clear_partial, mark_partial
    from nerfedit_plugin.io.faults import fault_point
    from nerfedit_plugin.render.animation import render_key, settings_digest
    from nerfedit_plugin.render.views import default_render_config, render_views, write_images

    field = run.field()
    transforms = read_transforms(cameras, "test" if Path(cameras).is_dir() else None)
    names = [p.with_suffix(".png").name for p in transforms.image_paths]
    views = run_cameras(run, transforms.cameras, frame_of_cameras, downscale)
    bent = load_deformation(deformation) if deformation is not None else None
    config = default_render_config(field)
    frames = list(range(bent.n_frames if bent is not None else 1)) if frames is None else list(frames)
    digest = settings_digest(Path(out), render_key(run, deformation, supersample, frames, views), resume)
    with atomic_dir(out, overwrite, keep_partial=len(frames) > 1, resume=resume) as stage:
        if len(frames) > 1:
            mark_partial(stage, {"frames": frames, "key": digest})
        for f in frames:
            folder = stage if len(frames) == 1 else stage / f"frame_{f:04d}"
            if folder != stage and folder.is_dir():  # finished before an interruption (--resume)
                continue
            images = render_views(field, views, config, deformation=bent, frame=f, supersample=supersample)
            write_images(images, names, folder)
            fault_point("render.frame")
        if record is not None:
            write_config(stage / CONFIG, record)
        clear_partial(stage)
    return Path(out)


def run_cameras(run, cameras, frame_of_cameras: str, downscale: int):
    """``cameras`` in the run's world frame (``frame_of_cameras == "capture"``: mapped by ``run.source_transform()``),
    downscaled by ``downscale``."""
    if frame_of_cameras == "capture":
        cameras = cameras.transformed(run.source_transform())
    return cameras.downscale(downscale) if downscale > 1 else cameras


def render(args: RenderArgs) -> None:
    import torch

    from nerfedit_plugin.bending.scene_deformation import load_deformation
    from nerfedit_plugin.cli.view import run_up
    from nerfedit_plugin.io.run import open_run
    from nerfedit_plugin.render.animation import orbit_shots, parse_frames, render_animation, render_key, trajectory
    from nerfedit_plugin.render.executors import RenderJob, make_executor

    run = open_run(args.run)
    n_frames = load_deformation(args.deformation).n_frames if args.deformation is not None else 1
    frames = parse_frames(args.frame, n_frames)
    if args.trajectory == "views":
        if args.cameras is None:
            raise NerfEditError("--cameras: needed by --trajectory views (a transforms file or dataset folder)")
        for given, flag in ((args.video, "--video"), (args.executor != "local", "--executor ray")):
            if given:
                raise NerfEditError(f"{flag}: for animations (--trajectory fixed, orbit or path), not views")
        out = render_run(
            run, args.cameras, args.deformation, frames, args.out, args.overwrite, args.supersample,
            recorded(args), args.resume, args.frame_of_cameras, args.downscale,
        )  # fmt: skip
        console.print(f"renders → {out}")
        return
    orbit = args.trajectory == "orbit"
    box, up, ring = None, (0.0, 0.0, 1.0), None
    if orbit:
        box, up = run.field("cpu").scene_bbox, run_up(run) or up
        ring, frames = run.filming(box, up), orbit_shots(frames, args.shots)
    cameras, path_fps = trajectory(
        args.trajectory, frames, cameras=args.cameras, view=args.view, size=args.size, scene_bbox=box, up=up, ring=ring
    )
    cameras = run_cameras(run, cameras, "world" if orbit else args.frame_of_cameras, args.downscale)
    job = RenderJob(run.path, args.deformation, args.supersample, torch.get_num_threads())
    key = render_key(run, args.deformation, args.supersample, frames, cameras)
    executor = make_executor(args.executor, job, args.ray_address, args.workers)
    try:
        out = render_animation(
            executor, frames, cameras, args.out, key=key, overwrite=args.overwrite, resume=args.resume,
            videos=args.video, fps=args.fps or path_fps or 24.0, record=recorded(args),
        )  # fmt: skip
    finally:
        executor.close()
    console.print(f"{len(frames)} {'shots' if orbit else 'frames'} → {out}")


COMMAND = Command("render", RenderArgs, render, records=True)
