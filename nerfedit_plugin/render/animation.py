"""Animations: the frames of a deformation rendered along a camera trajectory, one PNG per shot, then MP4 / GIF.

A *shot* is one image: (deformation frame, camera). Trajectories (:func:`trajectory`): ``fixed`` — camera ``view``
of a transforms file for every frame; ``orbit`` — one turn around the scene box, the frames spread over its shots
(:func:`orbit_shots`); ``path`` — camera ``i`` of a transforms file or of a nerfstudio ``camera_path.json`` for the
``i``-th frame.

:func:`render_animation` writes ``OUT/frame_NNNN.png`` (NNNN the deformation frame, or the shot when a frame is
shown more than once) through an executor
(:mod:`nerfedit_plugin.pipeline.executors`) into the output's staging folder, which is marked partial first with the
settings' key: an interrupted render leaves a partial output (docs/reliability.md), and ``resume`` continues it,
rendering only the shots whose PNG is missing (refused when the settings differ). Each PNG is written atomically,
so a frame on disk is whole; the video files and ``config.yml`` come last, then the marker goes.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from nerfedit_plugin.data.cameras import Cameras
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_dir, atomic_path, clear_partial, mark_partial, partial_info
from nerfedit_plugin.io.faults import fault_point

Trajectory = Literal["views", "fixed", "orbit", "path"]
STILL_ORBIT_SHOTS = 60
"""Shots of an orbit around a single frame (a still edit): a turn of 2.5 s at 24 fps."""


def parse_frames(spec: str | None, n_frames: int | None, option: str = "--frame") -> list[int]:
    """``None`` or ``all`` → every frame; ``N`` → ``[N]``; ``A:B`` or ``A:B:S`` → Python's ``range(A, B, S)``
    (``B`` exclusive, either end may be left out). Malformed or negative specs, and (given ``n_frames``; ``None``
    checks the syntax alone and returns ``[]``) frames outside ``[0, n_frames)`` or an empty range, are errors
    naming ``option``."""
    if spec is None or spec.strip() == "all":
        return list(range(n_frames or 0))
    parts = spec.split(":")
    try:
        numbers = [int(part) if part.strip() else None for part in parts]
    except ValueError:
        numbers = None
    if numbers is None or len(parts) > 3 or (len(parts) == 1 and numbers[0] is None):
        raise NerfEditError(f"{option}: expected N, A:B, A:B:STEP or all, got {spec!r}")
    if any(number is not None and number < 0 for number in numbers):
        raise NerfEditError(f"{option}: must be >= 0, got {spec!r}")
    if len(parts) == 3 and numbers[2] == 0:
        raise NerfEditError(f"{option}: the step must be positive, got {spec!r}")
    if n_frames is None:
        return []
    if len(parts) == 1:
        frames = numbers
    else:
        start, stop, step = (numbers + [None])[:3]
        frames = list(range(start or 0, n_frames if stop is None else stop, step or 1))
    bad = [f for f in frames if f >= n_frames]
    if bad or not frames:
        problem = f"frame {bad[0]} is out of range" if bad else "selects no frame"
        raise NerfEditError(f"{option}: {problem} (the deformation has {n_frames} frame(s), 0..{n_frames - 1})")
    return frames


def read_camera_path(path: str | os.PathLike) -> tuple[Cameras, float | None]:
    """A nerfstudio ``camera_path.json`` (what its viewer exports) → its perspective cameras and its ``fps``:
    ``render_width``/``render_height``, and per camera ``camera_to_world`` (16 numbers, row-major OpenGL
    camera-to-world) and ``fov`` (vertical, degrees; focal ``h / (2 tan(fov/2))``). Errors name the file and key."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise NerfEditError(f"{path}: cannot read the camera path ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("camera_path"), list) or not data["camera_path"]:
        raise NerfEditError(f"{path}: camera_path: expected a non-empty list of cameras")
    kind = data.get("camera_type", "perspective")
    if kind != "perspective":
        raise NerfEditError(f"{path}: camera_type: only perspective cameras are supported, got {kind!r}")
    size = []
    for key in ("render_width", "render_height"):
        value = data.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise NerfEditError(f"{path}: {key}: expected a positive integer, got {value!r}")
        size.append(value)
    width, height = size
    c2w, focal = [], []
    for i, camera in enumerate(data["camera_path"]):
        where = f"{path}: camera_path[{i}]"
        try:
            matrix = np.asarray(camera["camera_to_world"], dtype=np.float64).reshape(4, 4)
            fov = float(camera["fov"])
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise NerfEditError(f"{where}: expected camera_to_world (16 numbers) and fov ({exc!r})") from None
        if not np.isfinite(matrix).all() or not 0 < fov < 180:
            raise NerfEditError(f"{where}: camera_to_world must be finite and fov in (0, 180) degrees")
        c2w.append(matrix)
        focal.append(height / (2.0 * math.tan(math.radians(fov) / 2.0)))
    focal = torch.tensor(focal)
    cameras = Cameras(torch.tensor(np.stack(c2w)), focal, focal, width / 2.0, height / 2.0, width, height)
    fps = data.get("fps")
    return cameras, float(fps) if isinstance(fps, (int, float)) and not isinstance(fps, bool) and fps > 0 else None


def trajectory(
    kind: Trajectory,
    frames: Sequence[int],
    *,
    cameras: Path | None = None,
    view: int = 0,
    scene_bbox: torch.Tensor | None = None,
    size: int = 200,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    ring: dict | None = None,
) -> tuple[Cameras, float | None]:
    """One camera per shot of ``frames`` (and the camera path's fps, if it has one) for ``fixed``, ``orbit`` and
    ``path`` (see the module docstring); ``cameras`` is the transforms file or ``camera_path.json``; ``ring``: more
    keywords of the orbit's :func:`~nerfedit_plugin.render.views.turntable_cameras` (distance, elevation, fov)."""
    from nerfedit_plugin.render.views import turntable_cameras

    n = len(frames)
    if kind == "orbit":
        return turntable_cameras(scene_bbox, n, size, up=up, **(ring or {})), None
    if cameras is None:
        raise NerfEditError(f"--trajectory {kind}: needs --cameras (a transforms file or camera_path.json)")
    fps = None
    if kind == "path" and _is_camera_path(cameras):
        found, fps = read_camera_path(cameras)
    else:
        from nerfedit_plugin.data.datasets import read_transforms

        found = read_transforms(cameras, "test" if Path(cameras).is_dir() else None).cameras
    if kind == "fixed":
        if not 0 <= view < len(found):
            raise NerfEditError(f"--view: {view} is out of range ({cameras} has {len(found)} cameras)")
        return found[[view] * n], fps
    if len(found) < n:
        raise NerfEditError(f"--cameras: {cameras} has {len(found)} cameras for {n} frames (one per frame)")
    return found[list(range(n))], fps


def _is_camera_path(path: Path) -> bool:
    try:
        return path.is_file() and "camera_path" in json.loads(path.read_text())
    except (OSError, ValueError, TypeError):
        return False


def orbit_shots(frames: Sequence[int], shots: int | None) -> list[int]:
    """The deformation frame of each shot of an orbit of ``shots`` images over ``frames``, spread evenly (shot ``i``
    shows ``frames[i·F // shots]``); ``None``: one shot per frame, or :data:`STILL_ORBIT_SHOTS` of a single frame."""
    n = shots if shots is not None else (len(frames) if len(frames) > 1 else STILL_ORBIT_SHOTS)
    return [frames[i * len(frames) // n] for i in range(n)]


def shot_name(frame: int) -> str:
    return f"frame_{frame:04d}.png"


def render_key(
    run: Any, deformation: str | os.PathLike | None, supersample: int, frames: Sequence[int], cameras: Cameras
) -> dict:
    """What a render's images depend on, as plain data for :func:`settings_digest`."""
    return {
        "run": str(run.path.resolve()),
        "deformation": str(Path(deformation).resolve()) if deformation is not None else None,
        "supersample": supersample,
        "frames": list(frames),
        "cameras": [cameras.c2w.tolist(), cameras.fx.tolist(), cameras.width, cameras.height],
    }


def settings_digest(out: Path, key: dict, resume: bool) -> str:
    """The digest a partial render records of ``key`` (plain data: what its images depend on); with ``resume``, a
    partial output at ``out`` recorded with another digest (other settings: run, deformation, frames, cameras) is a
    :class:`NerfEditError`, so one render never mixes images of two settings."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]
    info = partial_info(out) if resume else None
    if info is not None and info.get("key") != digest:
        raise NerfEditError(f"{out}: --resume: the partial render was made with other settings; use --overwrite")
    return digest


def render_animation(
    executor: Any,
    frames: Sequence[int],
    cameras: Cameras,
    out: str | os.PathLike,
    *,
    key: dict,
    overwrite: bool = False,
    resume: bool = False,
    videos: Sequence[str] = (),
    fps: float = 24.0,
    record: Any = None,
    progress: bool = True,
) -> Path:
    """Render shot ``i`` = (``frames[i]``, camera ``i``) with ``executor`` into ``out/frame_NNNN.png``, NNNN the
    deformation frame (the shot ``i`` when a frame is shown more than once, as in an orbit of a still edit); ``key``
    (plain data: what the shots depend on) guards ``resume``; ``videos`` ⊂ {``mp4``, ``gif``} writes
    ``out/animation.mp4`` / ``.gif`` at ``fps``; ``record`` goes to ``out/config.yml``."""
    import skimage.io
    from rich.progress import Progress

    from nerfedit_plugin.config import write_config

    out = Path(out)
    digest = settings_digest(out, key, resume)
    names = [shot_name(f) for f in (frames if len(set(frames)) == len(frames) else range(len(frames)))]
    with atomic_dir(out, overwrite, keep_partial=True, resume=resume) as stage:
        mark_partial(stage, {"key": digest, "shots": len(frames)})
        todo = [i for i, name in enumerate(names) if not (stage / name).is_file()]
        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task("frames", total=len(frames), completed=len(frames) - len(todo))
            for i, image in executor.map([(frames[i], cameras[i]) for i in todo]):
                with atomic_path(stage / names[todo[i]]) as tmp:
                    skimage.io.imsave(tmp, image, check_contrast=False)
                bar.advance(task)
                fault_point("render.frame")
        paths = [stage / name for name in names]
        for kind in videos:
            write_video(stage / f"animation.{kind}", paths, fps)
        if record is not None:
            write_config(stage / "config.yml", record)
        clear_partial(stage)
    return out


def write_video(path: Path, frames: Sequence[Path], fps: float) -> Path:
    """An MP4 (H.264, imageio-ffmpeg's own ffmpeg) or a looping GIF (Pillow) of the PNGs ``frames`` at ``fps``,
    written atomically, reading one frame at a time (odd sizes are padded by a row/column of edge pixels: H.264
    needs even ones)."""
    import imageio.v2 as imageio

    if path.suffix == ".gif":
        from nerfedit_plugin.render.views import write_gif

        return write_gif(path, [imageio.imread(frame)[..., :3] / 255.0 for frame in frames], fps)
    with atomic_path(path) as tmp:
        writer = imageio.get_writer(tmp, format="FFMPEG", fps=fps, codec="libx264", macro_block_size=1)
        try:
            for frame in frames:
                image = imageio.imread(frame)[..., :3]
                pad = ((0, image.shape[0] % 2), (0, image.shape[1] % 2), (0, 0))
                writer.append_data(np.pad(image, pad, mode="edge"))
        finally:
            writer.close()
    return path
