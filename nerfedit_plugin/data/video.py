"""A capture from a video or a folder of photos (``nerfedit process``, like nerfstudio's ``ns-process-data``).

:func:`process_capture` writes ``OUT/images/`` — evenly spaced frames of a video (decoded by imageio-ffmpeg's own
ffmpeg) as ``frame_NNNN.png``, or the photos of a folder as ``NAME.png`` — each downsized so its longest side is at
most ``max_size`` px, then runs :func:`nerfedit_plugin.data.sfm.reconstruct` on them: ``OUT`` is a COLMAP workspace
that ``nerfedit train --data OUT`` reads. The folder is written atomically: an unreadable video, fewer than
:data:`MIN_IMAGES` frames or registered images leave nothing behind.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from nerfedit_plugin.data.sfm import reconstruct
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_dir

MIN_IMAGES = 3
"""Fewest frames (and registered images) a capture may have."""
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
"""Files of a photo folder that are read (case-insensitive)."""


def video_frames(video: str | os.PathLike, count: int) -> Iterator[np.ndarray]:
    """``count`` evenly spaced frames (the first and the last included) of ``video`` as ``(H, W, 3)`` uint8 arrays,
    in order; all of them when it has fewer. A file ffmpeg cannot read is a :class:`NerfEditError` naming it."""
    import imageio.v2 as imageio

    video = Path(video)
    if video.is_dir():
        raise NerfEditError(f"{video}: a folder, not a video file (a folder of photos is --images)")
    if not video.is_file():
        raise NerfEditError(f"{video}: no such video file")
    reader = None
    try:  # imageio raises OSError, RuntimeError or ValueError depending on the failure
        reader = imageio.get_reader(video, format="FFMPEG")
        total = reader.count_frames()
        wanted = set(np.linspace(0, total - 1, min(count, total)).round().astype(int).tolist()) if total else set()
        for index, frame in enumerate(reader):
            if index in wanted:
                yield np.asarray(frame)[..., :3]
    except Exception as exc:
        reason = [line for line in str(exc).splitlines() if line.strip()][-1:]  # ffmpeg's last word on it
        raise NerfEditError(f"{video}: not a video ffmpeg can read ({' '.join(reason)})") from exc
    finally:
        if reader is not None:
            reader.close()


def photos(folder: str | os.PathLike) -> list[Path]:
    """The photos of ``folder`` (:data:`PHOTO_SUFFIXES`), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise NerfEditError(f"{folder}: not a folder of photos")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)


def read_photo(path: Path) -> Image.Image:
    """The RGB image of the photo ``path``, upright (its EXIF orientation applied, as phones store it); a file that is
    not an image is a :class:`NerfEditError` naming it."""
    try:
        with Image.open(path) as image:
            return ImageOps.exif_transpose(image).convert("RGB")
    except OSError as exc:  # PIL's UnidentifiedImageError is an OSError
        raise NerfEditError(f"{path}: not an image ({exc})") from exc


def downsize(image: Image.Image, max_size: int | None) -> Image.Image:
    """``image`` shrunk (Lanczos) so that its longest side is at most ``max_size`` px; unchanged when it fits or
    ``max_size`` is None."""
    if max_size is None or max(image.size) <= max_size:
        return image
    scale = max_size / max(image.size)
    return image.resize([max(1, round(side * scale)) for side in image.size], Image.Resampling.LANCZOS)


def _write_images(folder: Path, video: Path | None, images: Path | None, frames: int, max_size: int | None) -> int:
    """Write the frames or photos into ``folder`` as PNGs; their number. Images of different sizes are an error (the
    capture has one camera)."""
    if video is not None:
        named = ((f"frame_{i:04d}", Image.fromarray(f)) for i, f in enumerate(video_frames(video, frames)))
    else:
        named = ((p.stem, read_photo(p)) for p in photos(images))
    written, size = 0, None
    for name, image in named:
        path = folder / f"{name}.png"
        if path.exists():
            raise NerfEditError(f"{images}: two photos are named {name} (the capture's images are {name}.png)")
        if size is not None and image.size != size:
            raise NerfEditError(
                f"{images}: {name} is {image.size[0]}x{image.size[1]}, the first photo {size[0]}x{size[1]}"
            )
        size = image.size
        downsize(image, max_size).save(path)
        written += 1
    return written


def process_capture(
    out: str | os.PathLike,
    *,
    video: str | os.PathLike | None = None,
    images: str | os.PathLike | None = None,
    frames: int = 60,
    max_size: int | None = 512,
    camera_model: str = "SIMPLE_RADIAL",
    overwrite: bool = False,
) -> tuple[Path, int, int]:
    """Write the COLMAP workspace ``out`` from ``video`` (``frames`` evenly spaced frames) or from the photo folder
    ``images`` (exactly one of them), every image downsized to ``max_size`` px, and reconstruct it (one
    ``camera_model`` camera). Returns the workspace, its number of images and of registered images; fewer than
    :data:`MIN_IMAGES` of either is a :class:`NerfEditError`, a partial registration a warning."""
    if (video is None) == (images is None):
        raise NerfEditError("process: give a video or a folder of images (--video / --images), exactly one")
    video, images = (None if p is None else Path(p) for p in (video, images))
    source, out = video or images, Path(out)
    with atomic_dir(out, overwrite) as stage:
        (stage / "images").mkdir()
        count = _write_images(stage / "images", video, images, frames, max_size)
        if count < MIN_IMAGES:
            raise NerfEditError(f"{source}: {count} frame(s); structure from motion needs at least {MIN_IMAGES}")
        registered = reconstruct(stage, camera_model)[1]
        if registered < MIN_IMAGES:
            raise NerfEditError(
                f"{source}: structure from motion registered {registered} of {count} images (at least {MIN_IMAGES} "
                "needed): more overlap between views, more texture, or less motion blur"
            )
    if registered < count:
        warnings.warn(
            f"{out}: structure from motion registered {registered} of {count} images; training uses those",
            stacklevel=2,
        )
    return out, count, registered
