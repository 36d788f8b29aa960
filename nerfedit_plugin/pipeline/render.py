"""``nerfedit render``: a run's field, edited or not, into a render folder — the cameras of a transforms file
(:func:`render_run`: ``OUT/NAME.png`` per camera, ``OUT/frame_NNNN/`` per deformation frame when there are several),
or an animation along a trajectory (:func:`render_trajectory`: ``OUT/frame_NNNN.png`` per shot, videos, through an
executor). Either folder holds ``config.yml`` (the command's record) and is written atomically; an interrupted
render of several frames stays as a partial folder that ``resume`` continues (same settings only)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from nerfedit_plugin.bending.scene_deformation import load_deformation
from nerfedit_plugin.config import write_config
from nerfedit_plugin.data.cameras import Cameras
from nerfedit_plugin.data.datasets import read_transforms
from nerfedit_plugin.io.atomic import atomic_dir, clear_partial, mark_partial
from nerfedit_plugin.io.faults import fault_point
from nerfedit_plugin.pipeline.executors import RenderJob, make_executor
from nerfedit_plugin.pipeline.run import CONFIG, Z_UP, Run
from nerfedit_plugin.render.animation import (
    Trajectory,
    orbit_shots,
    parse_frames,
    render_animation,
    render_key,
    settings_digest,
    trajectory,
)
from nerfedit_plugin.render.views import default_render_config, render_views, write_images


def render_run(
    run: Run,
    cameras: Path,
    deformation: Path | None,
    frames: str | None,
    out: Path,
    overwrite: bool,
    supersample: int = 1,
    record: Any = None,
    resume: bool = False,
    frame_of_cameras: str = "world",
    downscale: int = 1,
) -> Path:
    """Render ``run``'s field from every camera of a transforms file (bent by ``deformation`` at each of ``frames`` — N,
    A:B, A:B:STEP or all, the default: one frame into ``out``, several into ``out/frame_NNNN``) into PNGs named like the
    file's frames, atomically; several frames are kept as a partial output when interrupted, and ``resume`` continues
    one; ``record`` goes to ``out/config.yml``. ``frame_of_cameras`` and ``downscale``: see :func:`run_cameras`."""
    field = run.field()
    transforms = read_transforms(cameras, "test" if Path(cameras).is_dir() else None)
    names = [p.with_suffix(".png").name for p in transforms.image_paths]
    views = run_cameras(run, transforms.cameras, frame_of_cameras, downscale)
    bent = load_deformation(deformation) if deformation is not None else None
    config = default_render_config(field)
    frames = parse_frames(frames, bent.n_frames if bent is not None else 1)
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


def run_cameras(run: Run, cameras: Cameras, frame_of_cameras: str, downscale: int) -> Cameras:
    """``cameras`` in the run's world frame (``frame_of_cameras == "capture"``: mapped by ``run.source_transform()``),
    downscaled by ``downscale``."""
    if frame_of_cameras == "capture":
        cameras = cameras.transformed(run.source_transform())
    return cameras.downscale(downscale) if downscale > 1 else cameras


def render_trajectory(
    run: Run,
    kind: Trajectory,
    out: str | os.PathLike,
    *,
    deformation: Path | None = None,
    frames: str | None = None,
    cameras: Path | None = None,
    view: int = 0,
    size: int = 200,
    shots: int | None = None,
    supersample: int = 1,
    frame_of_cameras: str = "world",
    downscale: int = 1,
    videos: Sequence[str] = (),
    fps: float | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    workers: int | None = None,
    overwrite: bool = False,
    resume: bool = False,
    record: Any = None,
) -> tuple[Path, int]:
    """Render the frames (N, A:B, A:B:STEP or all) of ``deformation`` (None: the unedited field) along the trajectory
    ``kind`` (``fixed``, ``orbit``, ``path``: :func:`~nerfedit_plugin.render.animation.trajectory`) into ``out``
    with the ``local`` or ``ray`` executor → ``(out, shots rendered)``. An orbit flies where the run's training
    cameras stood (:meth:`Run.filming`; a run without cameras: the default ring) about the run's up, in ``shots``
    images (default: one per frame; 60 for a single frame); ``videos`` ⊂ {mp4, gif} at ``fps`` (default: the camera
    path's, else 24)."""
    n_frames = load_deformation(deformation).n_frames if deformation is not None else 1
    chosen = parse_frames(frames, n_frames)
    orbit = kind == "orbit"
    box, up, ring = None, Z_UP, None
    if orbit:
        box, up = run.field("cpu").scene_bbox, run.up() or Z_UP
        ring, chosen = run.filming(box, up), orbit_shots(chosen, shots)
    views, path_fps = trajectory(kind, chosen, cameras=cameras, view=view, size=size, scene_bbox=box, up=up, ring=ring)
    views = run_cameras(run, views, "world" if orbit else frame_of_cameras, downscale)
    job = RenderJob(run.path, deformation, supersample, torch.get_num_threads())
    key = render_key(run, deformation, supersample, chosen, views)
    runner = make_executor(executor, job, ray_address, workers)
    try:
        path = render_animation(
            runner, chosen, views, out, key=key, overwrite=overwrite, resume=resume, videos=videos,
            fps=fps or path_fps or 24.0, record=record,
        )  # fmt: skip
    finally:
        runner.close()
    return path, len(chosen)
