"""COLMAP workspaces: ``CAPTURE/images/`` and the sparse model ``CAPTURE/sparse/0/{cameras,images,points3D}.{bin,txt}``
(read with pycolmap, ``pip install "nerfedit[colmap]"``).

COLMAP poses are OpenCV world-to-camera ``[R | t]`` (``cam_from_world``); they are turned into OpenGL
camera-to-world matrices once, here (:func:`nerfedit_plugin.data.cameras.opengl_from_world_to_camera`), in COLMAP's
own world frame (the *capture* frame). Registered images are sorted by name. Images of the folder that the model did
not register are reported by a warning and left out; fewer than 3 registered images is an error.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nerfedit_plugin.data.cameras import opengl_from_world_to_camera
from nerfedit_plugin.data.lens import Lens
from nerfedit_plugin.errors import NerfEditError

MODEL_FILES = ("cameras", "images", "points3D")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")
MIN_IMAGES = 3


@dataclass
class ColmapModel:
    """A sparse model in the capture frame: per registered image ``c2w (C,4,4)`` OpenGL camera-to-world, its
    ``lens``, ``size`` (width, height) and image file; ``points (P,3)`` the 3-D points."""

    folder: Path
    sparse: Path
    c2w: np.ndarray
    lenses: list[Lens]
    sizes: list[tuple[int, int]]
    image_paths: list[Path]
    points: np.ndarray


def is_workspace(path: Path) -> bool:
    """A folder that looks like a COLMAP workspace (``sparse/`` or ``images/`` without a transforms file)."""
    return path.is_dir() and ((path / "sparse").is_dir() or (path / "images").is_dir())


def sparse_folder(folder: Path) -> Path:
    """``folder/sparse/0`` (or ``folder/sparse`` holding the model files); an error naming what is missing."""
    for candidate in (folder / "sparse" / "0", folder / "sparse"):
        if all(_model_file(candidate, name) is not None for name in MODEL_FILES):
            return candidate
    raise NerfEditError(
        f"{folder}: no COLMAP model in sparse/0 (expected sparse/0/{{{','.join(MODEL_FILES)}}}.bin or .txt; run "
        "COLMAP first — see docs/usage.md, 'Captures')"
    )


def _model_file(folder: Path, name: str) -> Path | None:
    for suffix in (".bin", ".txt"):
        if (folder / f"{name}{suffix}").is_file():
            return folder / f"{name}{suffix}"
    return None


def read_colmap(folder: str | os.PathLike) -> ColmapModel:
    """Read the workspace ``folder`` (see the module docstring); every problem is a :class:`NerfEditError` naming the
    file."""
    folder = Path(folder)
    images_dir = folder / "images"
    if not images_dir.is_dir():
        raise NerfEditError(f"{folder}: no images/ folder (a COLMAP workspace holds images/ and sparse/0/)")
    sparse = sparse_folder(folder)
    pycolmap = require_pycolmap()
    try:
        reconstruction = pycolmap.Reconstruction(str(sparse))
    except Exception as exc:  # pycolmap raises RuntimeError / ValueError with COLMAP's message
        raise NerfEditError(f"{sparse}: cannot read the COLMAP model ({' '.join(str(exc).split())[:200]})") from exc
    images = sorted((im for im in reconstruction.images.values() if im.has_pose), key=lambda im: im.name)
    if len(images) < MIN_IMAGES:
        raise NerfEditError(
            f"{sparse}: {len(images)} registered image(s); at least {MIN_IMAGES} are needed (the reconstruction "
            "failed: more overlap between views, or more texture in the scene)"
        )
    on_disk = sorted(p.name for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if len(images) < len(on_disk):
        warnings.warn(
            f"{sparse}: {len(images)} of the {len(on_disk)} images in {images_dir} are registered; training on those",
            stacklevel=2,
        )
    c2w, lenses, sizes, paths = [], [], [], []
    for image in images:
        path = images_dir / image.name
        if not path.is_file():
            raise NerfEditError(f"{sparse}: image {image.name!r} is registered but {path} is missing")
        camera = reconstruction.cameras[image.camera_id]
        where = f"{_model_file(sparse, 'cameras')}: camera {image.camera_id}"
        lenses.append(Lens.from_colmap(camera.model.name, camera.params, where))
        sizes.append((int(camera.width), int(camera.height)))
        c2w.append(opengl_from_world_to_camera(np.asarray(image.cam_from_world().matrix(), dtype=np.float64)))
        paths.append(path)
    points = np.array([p.xyz for p in reconstruction.points3D.values()], dtype=np.float64).reshape(-1, 3)
    return ColmapModel(folder, sparse, np.stack(c2w), lenses, sizes, paths, points)


def require_pycolmap():
    """The pycolmap module, or a :class:`NerfEditError` saying how to install it."""
    try:
        import pycolmap
    except ImportError as exc:
        raise NerfEditError('reading COLMAP models needs pycolmap: pip install "nerfedit[colmap]"') from exc
    return pycolmap
