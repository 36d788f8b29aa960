"""Render a field (optionally bent by a DeformationField) from a set of cameras into image files.

Images are composited over the render config's background and written as 8-bit RGB PNGs, atomically (the whole
folder appears at once). :func:`turntable_cameras` places cameras on a circle around the scene box for
:func:`write_gif` animations.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.bending.maps import BackwardMap
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.data.datasets import to_uint8
from nerfedit_plugin.fields.base import Field
from nerfedit_plugin.io.atomic import atomic_dir, atomic_path
from nerfedit_plugin.render.renderer import RenderConfig, render_image


def default_render_config(field: Field, background=(1.0, 1.0, 1.0)) -> RenderConfig:
    """Render with the field's :attr:`~nerfedit_plugin.fields.base.Field.render_samples`, else the renderer's
    default."""
    samples = field.render_samples or RenderConfig.n_samples
    return RenderConfig(n_samples=int(samples), background=tuple(background))


def render_views(
    field: Field,
    cameras: Cameras,
    config: RenderConfig,
    *,
    deformation: BackwardMap | None = None,
    frame: int = 0,
    supersample: int = 1,
    progress: bool = True,
) -> list[np.ndarray]:
    """Render every camera → list of ``(H,W,3)`` float32 arrays in [0,1] (a rich progress bar when ``progress``)."""
    from rich.progress import Progress

    images = []
    with Progress(transient=True, disable=not progress) as bar:
        task = bar.add_task("rendering", total=len(cameras))
        for i in range(len(cameras)):
            image = render_image(
                field, cameras, i, config, deformation=deformation, frame=frame, supersample=supersample
            )
            images.append(image.clamp(0.0, 1.0).cpu().numpy())
            bar.advance(task)
    return images


def write_images(
    images: Sequence[np.ndarray], names: Sequence[str], out_dir: str | os.PathLike, overwrite: bool = False
) -> list[Path]:
    """Write ``images`` as ``out_dir/<name>`` PNGs; the folder is created atomically."""
    import skimage.io

    with atomic_dir(out_dir, overwrite) as stage:
        for image, name in zip(images, names):
            skimage.io.imsave(stage / name, to_uint8(image), check_contrast=False)
    return [Path(out_dir) / name for name in names]


def write_gif(path: str | os.PathLike, images: Sequence[np.ndarray], fps: float = 12.0) -> Path:
    """An endlessly looping GIF of ``images`` at ``fps`` frames per second (Pillow), written atomically."""
    from PIL import Image

    frames = [Image.fromarray(to_uint8(image)) for image in images]
    with atomic_path(path) as tmp:
        frames[0].save(tmp, save_all=True, append_images=frames[1:], duration=round(1000.0 / fps), loop=0)
    return Path(path)


def turntable_cameras(
    scene_bbox: torch.Tensor,
    n: int,
    size: int,
    *,
    elevation_degrees: float = 20.0,
    distance: float = 2.5,
    fov_degrees: float | None = None,
    up: Sequence[float] = (0.0, 0.0, 1.0),
) -> Cameras:
    """``n`` cameras on a circle around the centre of ``scene_bbox``, in the plane perpendicular to ``up``,
    ``distance`` × the box's half-diagonal away and ``elevation_degrees`` above the box's equator, each
    ``size``×``size`` pixels; the default field of view frames the box's bounding ball."""
    box = torch.as_tensor(scene_bbox, dtype=torch.float64).cpu()
    center, radius = box.mean(0), float(torch.linalg.norm(box[1] - box[0]) / 2)
    axis = torch.as_tensor(up, dtype=torch.float64)
    axis = axis / torch.linalg.norm(axis)
    first = torch.eye(3, dtype=torch.float64)[int(torch.argmin(axis.abs()))]
    first = first - (first @ axis) * axis
    first = first / torch.linalg.norm(first)
    second = torch.linalg.cross(axis, first)  # (first, second) = (x, y) for z up
    angles = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    elevation = math.radians(elevation_degrees)
    ring = (
        math.cos(elevation) * (torch.cos(angles)[:, None] * first + torch.sin(angles)[:, None] * second)
        + math.sin(elevation) * axis
    )
    eyes = center + distance * radius * ring
    if fov_degrees is None and distance <= 1.0:
        raise ValueError(f"turntable_cameras: distance {distance} puts the cameras inside the box's ball: give a fov")
    fov = math.radians(fov_degrees) if fov_degrees is not None else 2.0 * math.asin(1.0 / distance)
    return Cameras.from_fov(look_at(eyes, center.expand(n, 3), up), size, size, fov)
