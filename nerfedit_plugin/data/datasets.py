"""Multi-view image datasets: Blender / NeRF-synthetic and nerfstudio ``transforms`` files (read and write).

One parser reads both: Blender (``transforms_{train,val,test}.json``, a global ``camera_angle_x``) and nerfstudio
(one ``transforms.json`` with ``fl_x, fl_y, cx, cy, w, h``; splits by ``{split}_filenames`` or a per-frame
``"split"`` key). ``transform_matrix`` is OpenGL camera-to-world in both (:mod:`nerfedit_plugin.data.cameras`).
RGBA images are composited ``rgb·α + background·(1 − α)`` (straight alpha). The full format, what is inferred and
what is rejected: docs/architecture.md, "Datasets".
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.data.cameras import Cameras
from nerfedit_plugin.errors import NerfEditError

SPLITS = ("train", "val", "test")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")


# ---- images ----------------------------------------------------------------------------------------------------
def read_image(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """``(rgb (H,W,3), alpha (H,W) or None)`` as float32 in [0,1]; 8/16-bit or float, grey or colour, ± alpha.

    Pillow (behind ``skimage.io``) decodes 16-bit *colour* PNGs at 8-bit precision (16-bit grey is exact)."""
    import skimage.io

    if not Path(path).is_file():
        raise NerfEditError(f"{path}: image not found")
    try:
        image = np.asarray(skimage.io.imread(path))
    except Exception as exc:  # imageio raises many types for corrupt files
        raise NerfEditError(f"{path}: not a readable image ({_image_problem(exc)})") from exc
    if image.dtype == np.uint8 or image.dtype == np.uint16:
        image = image.astype(np.float32) / np.iinfo(image.dtype).max
    elif image.dtype.kind == "f":
        image = image.astype(np.float32)
    else:
        raise NerfEditError(f"{path}: unsupported pixel type {image.dtype}")
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[2] not in (1, 2, 3, 4):
        raise NerfEditError(f"{path}: expected a grey, RGB or RGBA image, got array shape {image.shape}")
    colour_channels = 1 if image.shape[2] in (1, 2) else 3
    rgb = np.broadcast_to(image[..., :colour_channels], image.shape[:2] + (3,))
    alpha = image[..., colour_channels] if image.shape[2] in (2, 4) else None
    return np.ascontiguousarray(rgb), alpha


def _image_problem(exc: Exception) -> str:
    """What a decoder's exception says, in a few words (imageio's "no backend" advice names packages to install,
    which would not help with a file that is not an image)."""
    text = " ".join(str(exc).split())
    if not text or "backend" in text or "cannot identify image" in text:
        return "unknown format or corrupt data"
    return text if len(text) <= 160 else text[:157] + "..."


def to_uint8(image: np.ndarray) -> np.ndarray:
    """image (..., C) float in [0,1] (clipped) → (..., C) uint8, rounded to the nearest of 0..255."""
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_rgba(path: str | os.PathLike, rgb: np.ndarray, alpha: np.ndarray) -> None:
    """Write straight (non-premultiplied) ``rgb (H,W,3)`` and ``alpha (H,W)`` in [0,1] as an 8-bit RGBA PNG."""
    import skimage.io

    rgba = np.concatenate([rgb, alpha[..., None]], axis=-1)
    skimage.io.imsave(path, to_uint8(rgba), check_contrast=False)


def composite(rgb: np.ndarray, alpha: np.ndarray | None, background) -> np.ndarray:
    """Straight ``rgb`` over ``background``: ``rgb·α + background·(1 − α)``."""
    if alpha is None:
        return rgb
    a = alpha[..., None]
    return rgb * a + np.asarray(background, dtype=rgb.dtype) * (1.0 - a)


def block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """Average ``factor``×``factor`` pixel blocks of ``image (H,W,...)`` (a partial last block is cropped): the
    image of :meth:`Cameras.downscale`. Linear, so compositing commutes with it."""
    if factor == 1:
        return image
    h, w = image.shape[0] // factor, image.shape[1] // factor
    blocks = image[: h * factor, : w * factor].reshape((h, factor, w, factor) + image.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(image.dtype)


# ---- transforms files ------------------------------------------------------------------------------------------
@dataclass
class Transforms:
    """The cameras of a transforms file and the image file of each frame (which need not exist)."""

    cameras: Cameras
    image_paths: list[Path]
    file: Path
    meta: dict = field(repr=False)
    """The parsed JSON (extra keys such as ``aabb`` or ``supersample``)."""


def transforms_file(path: str | os.PathLike, split: str | None = None) -> Path:
    """The transforms JSON of ``path``: the file itself, or in a folder ``transforms_{split}.json``, else
    ``transforms.json``."""
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        raise NerfEditError(f"{path}: dataset not found")
    candidates = ([path / f"transforms_{split}.json"] if split else []) + [path / "transforms.json"]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise NerfEditError(f"{path}: no {' or '.join(c.name for c in candidates)} in this folder")


def read_transforms(path: str | os.PathLike, split: str | None = None) -> Transforms:
    """Parse a Blender or nerfstudio transforms file (or dataset folder); ``split`` selects nerfstudio frames."""
    if split is not None and split not in SPLITS:
        raise NerfEditError(f"split: expected one of {', '.join(SPLITS)}, got {split!r}")
    file = transforms_file(path, split)
    try:
        meta = json.loads(file.read_text())
    except (OSError, ValueError) as exc:  # ValueError: bad UTF-8, bad JSON, an integer of > 4300 digits
        raise NerfEditError(f"{file}: cannot read JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise NerfEditError(f"{file}: expected a JSON object at the top level")
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise NerfEditError(f"{file}: key 'frames': " + ("missing" if frames is None else "expected a non-empty list"))
    _check_camera_model(file, meta, "")
    indices = _split_indices(file, meta, frames, split)
    c2w, intrinsics, paths, size = [], [], [], None
    for i in indices:
        frame, where = frames[i], f"frames[{i}]"
        if not isinstance(frame, dict):
            raise NerfEditError(f"{file}: {where}: expected an object")
        _check_camera_model(file, frame, f"{where}.")
        paths.append(_image_path(file, frame, where))
        c2w.append(_matrix(file, frame, where))
        frame_size = _size(file, meta, frame, where, paths[-1])
        if size is not None and frame_size != size:
            raise NerfEditError(
                f"{file}: {where}: image size {frame_size[0]}x{frame_size[1]} differs from "
                f"{size[0]}x{size[1]} of the first frame (mixed image sizes are not supported)"
            )
        size = frame_size
        intrinsics.append(_intrinsics(file, meta, frame, where, *size))
    fx, fy, cx, cy = torch.tensor(intrinsics, dtype=torch.float32).T
    cameras = Cameras(torch.from_numpy(np.stack(c2w)), fx, fy, cx, cy, *size)
    return Transforms(cameras, paths, file, meta)


def _split_indices(file: Path, meta: dict, frames: list, split: str | None) -> list[int]:
    if split is None:
        return list(range(len(frames)))
    listed = meta.get(f"{split}_filenames")
    if listed is not None:
        if not isinstance(listed, list):
            raise NerfEditError(f"{file}: key '{split}_filenames': expected a list of file paths")
        wanted = {os.path.normpath(str(p)) for p in listed}
        chosen = [i for i, f in enumerate(frames) if os.path.normpath(str(_get(f, "file_path"))) in wanted]
    elif any(isinstance(f, dict) and "split" in f for f in frames):
        chosen = [i for i, f in enumerate(frames) if isinstance(f, dict) and f.get("split") == split]
    else:
        return list(range(len(frames)))
    if not chosen:
        raise NerfEditError(f"{file}: no frames belong to split '{split}'")
    return chosen


def _get(frame, key):
    return frame.get(key) if isinstance(frame, dict) else None


def _check_camera_model(file: Path, obj: dict, where: str) -> None:
    model = obj.get("camera_model")
    if model is not None and model not in PINHOLE_MODELS:
        raise NerfEditError(f"{file}: {where}camera_model: {model!r} is not supported (pinhole cameras only)")
    for key in DISTORTION_KEYS:
        if key in obj and _number(file, obj, key, where) != 0.0:
            raise NerfEditError(f"{file}: {where}{key}: lens distortion is not supported (undistort the images)")


def _number(file: Path, obj: dict, key: str, where: str) -> float:
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not _finite(value):
        raise NerfEditError(f"{file}: {where}{key}: expected a finite number, got {value!r}")
    return float(value)


def _finite(value: int | float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond float range (JSON allows it)
        return False


def _lookup(file: Path, meta: dict, frame: dict, key: str, where: str) -> float | None:
    """Per-frame value of ``key`` overriding the global one; None when neither has it."""
    if key in frame:
        return _number(file, frame, key, f"{where}.")
    if key in meta:
        return _number(file, meta, key, "")
    return None


def _image_path(file: Path, frame: dict, where: str) -> Path:
    value = frame.get("file_path")
    if not isinstance(value, str) or not value:
        problem = "missing key" if value is None else f"expected a path, got {value!r}"
        raise NerfEditError(f"{file}: {where}.file_path: {problem}")
    path = file.parent / value
    try:
        found = path.is_file()
    except (OSError, ValueError) as exc:  # e.g. a name longer than the file system allows, a NUL byte
        raise NerfEditError(
            f"{file}: {where}.file_path: invalid path ({exc.__class__.__name__}: {exc})"[:400]
        ) from None
    if found or path.suffix.lower() in (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff"):
        return path
    return path.with_name(path.name + ".png")  # Blender lists file paths without extension


def _matrix(file: Path, frame: dict, where: str) -> np.ndarray:
    key = f"{where}.transform_matrix"
    if "transform_matrix" not in frame:
        raise NerfEditError(f"{file}: {key}: missing key")
    rows = frame["transform_matrix"]
    if isinstance(rows, list) and any(
        isinstance(x, bool) for row in rows for x in (row if isinstance(row, list) else [row])
    ):
        raise NerfEditError(f"{file}: {key}: expected a 4x4 matrix of numbers, got booleans")
    try:
        matrix = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:  # OverflowError: an integer beyond float range
        raise NerfEditError(f"{file}: {key}: expected a 4x4 matrix of numbers ({exc})") from exc
    if matrix.shape == (3, 4):
        matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
    if matrix.shape != (4, 4):
        raise NerfEditError(f"{file}: {key}: expected a 4x4 matrix, got shape {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise NerfEditError(f"{file}: {key}: contains NaN or Inf")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise NerfEditError(f"{file}: {key}: last row must be [0, 0, 0, 1], got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-3):
        raise NerfEditError(f"{file}: {key}: rotation part is not orthonormal (scaled or sheared camera)")
    return matrix


def _size(file: Path, meta: dict, frame: dict, where: str, image: Path) -> tuple[int, int]:
    w, h = _lookup(file, meta, frame, "w", where), _lookup(file, meta, frame, "h", where)
    if w is None or h is None:
        if not image.is_file():
            missing = "w" if w is None else "h"
            raise NerfEditError(f"{file}: missing key '{missing}' and image {image} not found to read the size")
        rgb, _ = read_image(image)
        return rgb.shape[1], rgb.shape[0]
    if w != int(w) or h != int(h) or w < 1 or h < 1:
        raise NerfEditError(f"{file}: {where}: w, h must be positive integers, got {w}, {h}")
    return int(w), int(h)


def _intrinsics(file: Path, meta: dict, frame: dict, where: str, w: int, h: int) -> tuple[float, ...]:
    fx = _lookup(file, meta, frame, "fl_x", where)
    if fx is None:
        angle = _lookup(file, meta, frame, "camera_angle_x", where)
        if angle is None:
            raise NerfEditError(f"{file}: missing key 'fl_x' (nerfstudio) or 'camera_angle_x' (Blender)")
        if not 0.0 < angle < math.pi:
            raise NerfEditError(f"{file}: camera_angle_x: expected radians in (0, pi), got {angle}")
        fx = 0.5 * w / math.tan(0.5 * angle)
    fy = _lookup(file, meta, frame, "fl_y", where)
    if fy is None:
        angle_y = _lookup(file, meta, frame, "camera_angle_y", where)
        if angle_y is not None and not 0.0 < angle_y < math.pi:
            raise NerfEditError(f"{file}: camera_angle_y: expected radians in (0, pi), got {angle_y}")
        fy = fx if angle_y is None else 0.5 * h / math.tan(0.5 * angle_y)
    if fx <= 0 or fy <= 0:
        raise NerfEditError(f"{file}: {where}: focal lengths must be positive, got fl_x={fx}, fl_y={fy}")
    cx, cy = _lookup(file, meta, frame, "cx", where), _lookup(file, meta, frame, "cy", where)
    return fx, fy, w / 2.0 if cx is None else cx, h / 2.0 if cy is None else cy


def world_up(cameras: Cameras, snap_degrees: float = 25.0) -> tuple[float, float, float] | None:
    """The world's up direction as the cameras see it: the mean of their up vectors (``c2w[:, :3, 1]``, OpenGL),
    snapped to the nearest signed axis when within ``snap_degrees`` of it; None when they do not agree on one (the
    mean is shorter than half a unit vector). Cameras placed with a world-up convention (Blender and `nerfedit
    generate` datasets: +z) give that axis."""
    ups = cameras.c2w[:, :3, 1].double().cpu().numpy()
    mean = ups.mean(0)
    norm = float(np.linalg.norm(mean))
    if not norm > 0.5:
        return None
    mean /= norm
    axis = int(np.abs(mean).argmax())
    if abs(mean[axis]) >= math.cos(math.radians(snap_degrees)):
        mean = np.eye(3)[axis] * np.sign(mean[axis])
    return tuple(float(v) for v in mean)


def blender_transforms(cameras: Cameras, file_paths: list[str]) -> dict:
    """Blender transforms dict (``camera_angle_x``, ``w``, ``h``, frames). Needs one focal length shared by all
    cameras, square pixels and a centred principal point (else use :func:`nerfstudio_transforms`)."""
    fx = cameras.fx[0]
    if not (
        torch.allclose(cameras.fx, fx)
        and torch.allclose(cameras.fy, fx)
        and torch.allclose(cameras.cx, torch.tensor(cameras.width / 2.0))
        and torch.allclose(cameras.cy, torch.tensor(cameras.height / 2.0))
    ):
        raise ValueError("Blender format needs one focal length, square pixels and a centred principal point")
    return {
        "camera_angle_x": float(cameras.camera_angle_x[0]),
        "w": cameras.width,
        "h": cameras.height,
        "frames": [{"file_path": p, "transform_matrix": m.tolist()} for p, m in zip(file_paths, cameras.c2w.cpu())],
    }


def nerfstudio_transforms(cameras: Cameras, file_paths: list[str]) -> dict:
    """nerfstudio transforms dict: the first camera's intrinsics are global, other cameras' differing ones are
    written per frame (nerfstudio's override)."""
    keys = ("fl_x", "fl_y", "cx", "cy")
    values = torch.stack([cameras.fx, cameras.fy, cameras.cx, cameras.cy], dim=1).cpu().tolist()
    frames = []
    for path, matrix, row in zip(file_paths, cameras.c2w.cpu(), values):
        frame = {"file_path": path, "transform_matrix": matrix.tolist()}
        frame.update({k: v for k, v, v0 in zip(keys, row, values[0]) if v != v0})
        frames.append(frame)
    return {
        "camera_model": "OPENCV",
        **dict(zip(keys, values[0])),
        "w": cameras.width,
        "h": cameras.height,
        "frames": frames,
    }


# ---- datasets --------------------------------------------------------------------------------------------------
@dataclass
class Dataset:
    """Images of one split with their cameras.

    ``images (C,H,W,3)`` float32 in [0,1], already composited over ``background``; ``alpha (C,H,W)`` when the
    files have an alpha channel (1 for frames that lack one), else None. ``scene_bbox (2,3)`` = [min, max]: the
    file's ``aabb`` key when present, else :func:`estimate_scene_bbox`.
    """

    images: torch.Tensor
    cameras: Cameras
    split: str
    image_paths: list[Path]
    background: tuple[float, float, float]
    scene_bbox: torch.Tensor
    alpha: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.cameras)

    def to(self, device: torch.device | str) -> Dataset:
        alpha = None if self.alpha is None else self.alpha.to(device)
        return Dataset(
            self.images.to(device),
            self.cameras.to(device),
            self.split,
            self.image_paths,
            self.background,
            self.scene_bbox.to(device),
            alpha,
        )


def estimate_scene_bbox(cameras: Cameras) -> torch.Tensor:
    """Cube around the point nearest (least squares) to all optical axes, of half-size ``min_i D_i sin θ_i``
    (``D_i`` = camera distance, ``θ_i`` = half the smaller field of view): a ball every camera sees whole."""
    c2w = cameras.c2w.double().cpu()
    origins, axes = c2w[:, :3, 3], -c2w[:, :3, 2]
    projector = torch.eye(3, dtype=torch.float64) - axes[:, :, None] * axes[:, None, :]
    lhs, rhs = projector.sum(0), (projector @ origins[:, :, None]).sum(0)[:, 0]
    center = torch.linalg.lstsq(lhs, rhs).solution if len(cameras) > 1 else origins[0] + axes[0]
    half_fov = torch.minimum(
        torch.atan(0.5 * cameras.width / cameras.fx.double().cpu()),
        torch.atan(0.5 * cameras.height / cameras.fy.double().cpu()),
    )
    radius = (torch.linalg.norm(origins - center, dim=1) * torch.sin(half_fov)).min()
    return torch.stack([center - radius, center + radius]).float().to(cameras.device)


def load_dataset(
    path: str | os.PathLike, split: str = "train", background=(1.0, 1.0, 1.0), downscale: int = 1
) -> Dataset:
    """Load a Blender or nerfstudio dataset (folder or transforms file) — see the module docstring — with images
    composited over ``background`` and downscaled by an integer ``downscale`` (block averaging)."""
    background = _background(background)
    if isinstance(downscale, bool) or int(downscale) != downscale or downscale < 1:
        raise NerfEditError(f"downscale: expected a positive integer, got {downscale!r}")
    downscale = int(downscale)
    transforms = read_transforms(path, split)
    cameras = transforms.cameras
    if cameras.width < downscale or cameras.height < downscale:
        raise NerfEditError(f"downscale: factor {downscale} exceeds the image size {cameras.width}x{cameras.height}")
    images, alphas, any_alpha = [], [], False
    for i, image_path in enumerate(transforms.image_paths):
        if not image_path.is_file():
            raise NerfEditError(f"{transforms.file}: frames[{i}].file_path: image {image_path} not found")
        rgb, alpha = read_image(image_path)
        if rgb.shape[:2] != (cameras.height, cameras.width):
            raise NerfEditError(
                f"{image_path}: image is {rgb.shape[1]}x{rgb.shape[0]} but {transforms.file.name} says "
                f"w={cameras.width}, h={cameras.height}"
            )
        any_alpha |= alpha is not None
        images.append(block_mean(composite(rgb, alpha, background), downscale))
        alphas.append(block_mean(np.ones(rgb.shape[:2], np.float32) if alpha is None else alpha, downscale))
    cameras = cameras.downscale(downscale)
    bbox = transforms.meta.get("aabb")
    if bbox is not None:
        try:
            bbox = torch.tensor(bbox, dtype=torch.float32)
        except (TypeError, ValueError) as exc:
            raise NerfEditError(f"{transforms.file}: aabb: expected [[x,y,z],[x,y,z]] ({exc})") from exc
        if bbox.shape != (2, 3) or not (bbox[0] < bbox[1]).all():
            raise NerfEditError(f"{transforms.file}: aabb: expected [[min x,y,z],[max x,y,z]] with min < max")
    else:
        bbox = estimate_scene_bbox(cameras)
    return Dataset(
        images=torch.from_numpy(np.stack(images)),
        cameras=cameras,
        split=split,
        image_paths=transforms.image_paths,
        background=background,
        scene_bbox=bbox,
        alpha=torch.from_numpy(np.stack(alphas)) if any_alpha else None,
    )


def _background(background) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in background)
    except (TypeError, ValueError):
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise NerfEditError(f"background: expected 3 numbers in [0, 1], got {background!r}")
    return values
