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

from nerfedit_plugin.data.bounds import estimate_scene_bbox
from nerfedit_plugin.data.cameras import OPENCV_TO_OPENGL, Cameras
from nerfedit_plugin.data.colmap import ColmapModel, is_workspace, read_colmap, sparse_folder
from nerfedit_plugin.data.image_cache import cached
from nerfedit_plugin.data.lens import DISTORTION, Lens
from nerfedit_plugin.data.normalization import apply, box_bounds, normalize_capture
from nerfedit_plugin.data.undistort import undistort_image
from nerfedit_plugin.errors import NerfEditError

SPLITS = ("train", "val", "test")
PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
"""nerfstudio ``camera_model`` values read (OPENCV with ``k1, k2, k3, p1, p2``: the images are undistorted on load)."""
CAPTURE_KEYS = ("applied_transform", "ply_file_path")
"""A nerfstudio file with one of these keys is a capture (``ns-process-data`` output): it is normalised."""
EVAL_INTERVAL = 8
"""nerfstudio's ``eval_interval``: every 8th frame of a file without split keys is held out."""
INRIA_CAMERAS = "cameras.json"
"""The INRIA 3D Gaussian Splatting trainer's cameras file, in its output folder beside ``point_cloud/``."""
INRIA_KEYS = ("width", "height", "position", "rotation", "fx", "fy")


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
    """The cameras of a transforms file (or COLMAP workspace) and the image file of each frame (which need not
    exist); for captures also each frame's ``lens`` (its distortion, undone on load) and ``mask`` file."""

    cameras: Cameras
    image_paths: list[Path]
    file: Path
    meta: dict = field(repr=False)
    """The parsed JSON (extra keys such as ``aabb`` or ``supersample``); a normalised capture's ``source_transform``
    and ``aabb`` (the foreground box) in the world frame."""
    lenses: list[Lens | None] = field(default_factory=list, repr=False)
    """Per frame: the lens when it has distortion, else None (empty: no frame has any)."""
    mask_paths: list[Path | None] = field(default_factory=list, repr=False)
    """Per frame: its mask image (0 = ignore the pixel) or None (empty: no frame has one)."""
    points: np.ndarray | None = field(default=None, repr=False)
    """A capture's sparse points ``(P,3)`` in the world frame (COLMAP ``points3D``, ``ply_file_path``), or None."""


def transforms_file(path: str | os.PathLike, split: str | None = None) -> Path:
    """The transforms JSON of ``path``: the file itself, or in a folder ``transforms_{split}.json``, else
    ``transforms.json``, else the INRIA trainer's ``cameras.json``."""
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        raise NerfEditError(f"{path}: dataset not found")
    candidates = ([path / f"transforms_{split}.json"] if split else []) + [path / "transforms.json"]
    candidates.append(path / INRIA_CAMERAS)
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    if is_workspace(path):
        return sparse_folder(path)
    raise NerfEditError(f"{path}: no {' or '.join(c.name for c in candidates)} in this folder")


def read_transforms(path: str | os.PathLike, split: str | None = None) -> Transforms:
    """Parse a Blender or nerfstudio transforms file, a COLMAP workspace (dataset folder) or the INRIA trainer's
    ``cameras.json`` (:func:`inria_cameras`; it has no splits); ``split`` selects frames. Captures (COLMAP
    workspaces, nerfstudio files with ``applied_transform`` or ``ply_file_path``) are normalised
    (:mod:`nerfedit_plugin.data.normalization`)."""
    if split is not None and split not in SPLITS:
        raise NerfEditError(f"split: expected one of {', '.join(SPLITS)}, got {split!r}")
    file = transforms_file(path, split)
    if file.is_dir():
        return _colmap_transforms(read_colmap(file.parent.parent if file.name == "0" else file.parent), split)
    try:
        meta = json.loads(file.read_text())
    except (OSError, ValueError) as exc:  # ValueError: bad UTF-8, bad JSON, an integer of > 4300 digits
        raise NerfEditError(f"{file}: cannot read JSON ({exc})") from exc
    if isinstance(meta, list) and meta and isinstance(meta[0], dict) and "position" in meta[0]:
        return inria_cameras(file, meta)  # no splits: every camera
    if not isinstance(meta, dict):
        raise NerfEditError(f"{file}: expected a JSON object at the top level")
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise NerfEditError(f"{file}: key 'frames': " + ("missing" if frames is None else "expected a non-empty list"))
    _check_camera_model(file, meta, "")
    c2w, intrinsics, lenses, paths, masks, size = [], [], [], [], [], None
    for i, frame in enumerate(frames):
        where = f"frames[{i}]"
        if not isinstance(frame, dict):
            raise NerfEditError(f"{file}: {where}: expected an object")
        _check_camera_model(file, frame, f"{where}.")
        paths.append(_image_path(file, frame, where))
        masks.append(_mask_path(file, frame, where))
        c2w.append(_matrix(file, frame, where))
        frame_size = _size(file, meta, frame, where, paths[-1])
        if size is not None and frame_size != size:
            raise NerfEditError(
                f"{file}: {where}: image size {frame_size[0]}x{frame_size[1]} differs from "
                f"{size[0]}x{size[1]} of the first frame (mixed image sizes are not supported)"
            )
        size = frame_size
        intrinsics.append(_intrinsics(file, meta, frame, where, *size))
        lenses.append(_lens(file, meta, frame, where, intrinsics[-1]))
    fx, fy, cx, cy = torch.tensor(intrinsics, dtype=torch.float32).T
    cameras = Cameras(torch.from_numpy(np.stack(c2w)), fx, fy, cx, cy, *size)
    if any(key in meta for key in CAPTURE_KEYS):
        applied = _applied_transform(file, meta)
        points = _ply_points(file, meta)
        cameras = cameras.transformed(np.linalg.inv(applied))  # to the capture frame (COLMAP's)
        points = None if points is None else apply(np.linalg.inv(applied), points)
        meta = _normalized(file, meta, cameras, points, applied)
        cameras = cameras.transformed(meta["source_transform"])
        points = None if points is None else apply(np.asarray(meta["source_transform"]), points)
    else:
        points = None
    chosen = _split_indices(file, meta, frames, split)
    return _select(Transforms(cameras, paths, file, meta, lenses, masks, points), chosen)


def inria_cameras(file: Path, entries: list) -> Transforms:
    """The cameras of the INRIA 3D Gaussian Splatting trainer's ``cameras.json``: a list of ``{"img_name", "width",
    "height", "position", "rotation", "fx", "fy"}`` (optionally ``cx``, ``cy``; else the image centre), ``rotation``
    and ``position`` the OpenCV camera-to-world rotation (rows) and centre → :class:`Transforms` of OpenGL cameras
    (``[rotation | position] · diag(1, −1, −1, 1)``), image paths ``img_name`` beside the file."""
    c2w, intrinsics, paths, size = [], [], [], None
    for i, entry in enumerate(entries):
        where = f"[{i}]."
        if not isinstance(entry, dict):
            raise NerfEditError(f"{file}: [{i}]: expected an object")
        missing = [key for key in INRIA_KEYS if key not in entry]
        if missing:
            raise NerfEditError(f"{file}: {where}{missing[0]}: missing key (an INRIA cameras.json entry)")
        frame_size = tuple(int(_number(file, entry, key, where)) for key in ("width", "height"))
        if min(frame_size) <= 0:
            raise NerfEditError(f"{file}: {where}width/height: expected positive sizes, got {list(frame_size)}")
        if size is not None and frame_size != size:
            raise NerfEditError(
                f"{file}: {where}width/height: image size {frame_size[0]}x{frame_size[1]} differs from "
                f"{size[0]}x{size[1]} of the first camera (mixed image sizes are not supported)"
            )
        size = frame_size
        try:
            rotation = np.asarray(entry["rotation"], dtype=np.float64)
            position = np.asarray(entry["position"], dtype=np.float64)
        except (TypeError, ValueError, OverflowError) as exc:
            raise NerfEditError(f"{file}: {where}rotation/position: expected numbers ({exc})") from exc
        if rotation.shape != (3, 3) or position.shape != (3,):
            raise NerfEditError(
                f"{file}: {where}rotation/position: expected a 3x3 matrix and 3 numbers, got shapes "
                f"{rotation.shape} and {position.shape}"
            )
        if not (np.isfinite(rotation).all() and np.isfinite(position).all()):
            raise NerfEditError(f"{file}: {where}rotation/position: contains NaN or Inf")
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-3):
            raise NerfEditError(f"{file}: {where}rotation: not orthonormal")
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rotation, position
        c2w.append(pose @ OPENCV_TO_OPENGL)
        focal = [_number(file, entry, key, where) for key in ("fx", "fy")]
        centre = [_number(file, entry, k, where) if k in entry else 0.5 * n for k, n in zip(("cx", "cy"), size)]
        intrinsics.append((*focal, *centre))
        name = entry.get("img_name", f"{i:05d}")
        paths.append(file.parent / str(name))
    fx, fy, cx, cy = torch.tensor(intrinsics, dtype=torch.float32).T
    cameras = Cameras(torch.from_numpy(np.stack(c2w)), fx, fy, cx, cy, *size)
    return Transforms(cameras, paths, file, {"cameras": "inria"})


def is_capture(transforms: Transforms) -> bool:
    """Whether ``transforms`` came from a capture that was normalised (a COLMAP model, an ``ns-process-data`` file)."""
    return transforms.file.is_dir() or any(key in transforms.meta for key in CAPTURE_KEYS)


def _colmap_transforms(model: ColmapModel, split: str | None) -> Transforms:
    """The normalised :class:`Transforms` of a COLMAP model (one image size; frames sorted by name)."""
    sizes = set(model.sizes)
    if len(sizes) > 1:
        raise NerfEditError(f"{model.sparse}: cameras of different image sizes {sorted(sizes)} are not supported")
    fx, fy, cx, cy = torch.tensor([(n.fx, n.fy, n.cx, n.cy) for n in model.lenses], dtype=torch.float32).T
    cameras = Cameras(torch.from_numpy(model.c2w), fx, fy, cx, cy, *model.sizes[0])
    meta = _normalized(model.sparse, {}, cameras, model.points, np.eye(4))
    frames = [{"file_path": p.name} for p in model.image_paths]
    points = apply(np.asarray(meta["source_transform"]), model.points) if len(model.points) else None
    transforms = Transforms(
        cameras.transformed(meta["source_transform"]), model.image_paths, model.sparse, meta, points=points
    )
    transforms.lenses = [n if n.distorted else None for n in model.lenses]
    return _select(transforms, _split_indices(model.sparse, meta, frames, split, interval=True))


def _normalized(file: Path, meta: dict, cameras: Cameras, points: np.ndarray | None, applied: np.ndarray) -> dict:
    """``meta`` with the capture's ``source_transform`` (capture → world) and ``aabb`` (the foreground box, unless
    the file gives one, which is in the file's frame: ``applied`` takes the capture frame there)."""
    source, box = normalize_capture(cameras, points)
    if "aabb" in meta:
        box = box_bounds(source @ np.linalg.inv(applied), _aabb(file, meta).numpy())
    return {**meta, "source_transform": source.tolist(), "aabb": box.tolist()}


def _select(transforms: Transforms, chosen: list[int]) -> Transforms:
    def pick(items: list) -> list:
        return [items[i] for i in chosen] if any(item is not None for item in items) else []

    return Transforms(
        transforms.cameras[chosen],
        [transforms.image_paths[i] for i in chosen],
        transforms.file,
        transforms.meta,
        pick(transforms.lenses),
        pick(transforms.mask_paths),
        transforms.points,
    )


def _split_indices(file: Path, meta: dict, frames: list, split: str | None, interval: bool | None = None) -> list[int]:
    """The frames of ``split``: listed in ``{split}_filenames``, or with ``"split": split``; else, for a file of all
    splits (``transforms.json``, a COLMAP model: ``interval``) of at least :data:`EVAL_INTERVAL` frames, nerfstudio's
    held-out split — every :data:`EVAL_INTERVAL`-th frame is ``val`` and ``test``, the others ``train``; else (a
    per-split file, a handful of frames) every split is all frames."""
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
    elif (interval if interval is not None else file.name == "transforms.json") and len(frames) >= EVAL_INTERVAL:
        held_out = split != "train"
        chosen = [i for i in range(len(frames)) if (i % EVAL_INTERVAL == 0) == held_out]
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
        raise NerfEditError(
            f"{file}: {where}camera_model: {model!r} is not supported ({', '.join(PINHOLE_MODELS)}; fisheye and "
            "panoramic cameras are not)"
        )


def _lens(file: Path, meta: dict, frame: dict, where: str, intrinsics: tuple[float, ...]) -> Lens | None:
    """The frame's lens when it has distortion (per-frame keys override the global ones), else None. Distortion
    needs nerfstudio intrinsics (``fl_x``) and a camera model that has it; ``k4`` (fisheye) is refused."""
    values = {k: _lookup(file, meta, frame, k, where) or 0.0 for k in (*DISTORTION, "k4")}
    given = [k for k, v in values.items() if v != 0.0]
    if not given:
        return None
    key = f"{where}.{given[0]}" if given[0] in frame else given[0]
    if _lookup(file, meta, frame, "fl_x", where) is None:
        raise NerfEditError(
            f"{file}: {key}: lens distortion is not supported with camera_angle_x (Blender intrinsics): give fl_x, "
            "fl_y, cx, cy and camera_model OPENCV (nerfstudio)"
        )
    model = frame.get("camera_model", meta.get("camera_model", "OPENCV"))
    if model != "OPENCV":
        raise NerfEditError(f"{file}: {key}: lens distortion with camera_model {model!r}; distorted lenses are OPENCV")
    if values.pop("k4"):
        raise NerfEditError(f"{file}: {where}: k4 is a fisheye coefficient (OPENCV_FISHEYE), which is not supported")
    return Lens(*intrinsics, **values)


def _mask_path(file: Path, frame: dict, where: str) -> Path | None:
    value = frame.get("mask_path")
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise NerfEditError(f"{file}: {where}.mask_path: expected a path, got {value!r}")
    return file.parent / value


def _applied_transform(file: Path, meta: dict) -> np.ndarray:
    """(4,4) nerfstudio's ``applied_transform`` (3×4: COLMAP's frame → the file's), the identity when absent."""
    if "applied_transform" not in meta:
        return np.eye(4)
    try:
        matrix = np.asarray(meta["applied_transform"], dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        matrix = np.zeros(0)
    if matrix.shape in ((3, 4), (4, 4)):
        matrix = np.vstack([matrix[:3], [0.0, 0.0, 0.0, 1.0]])
        if np.isfinite(matrix).all() and np.allclose(matrix[:3, :3].T @ matrix[:3, :3], np.eye(3), atol=1e-4):
            return matrix
    raise NerfEditError(f"{file}: applied_transform: expected a 3x4 rigid transform (rotation and translation)")


def _ply_points(file: Path, meta: dict) -> np.ndarray | None:
    """The sparse points of ``ply_file_path`` (in the file's frame), or None."""
    value = meta.get("ply_file_path")
    if value is None:
        return None
    path = file.parent / str(value)
    if not path.is_file():
        raise NerfEditError(f"{file}: ply_file_path: {path} not found")
    import trimesh

    try:
        points = np.asarray(trimesh.load(path, process=False).vertices, dtype=np.float64)
    except Exception as exc:  # trimesh raises many types for a bad file
        raise NerfEditError(f"{path}: not a readable PLY point cloud ({exc})"[:300]) from exc
    return points[np.isfinite(points).all(1)]


def _aabb(file: Path, meta: dict) -> torch.Tensor:
    try:
        bbox = torch.tensor(meta["aabb"], dtype=torch.float32)
    except (TypeError, ValueError) as exc:
        raise NerfEditError(f"{file}: aabb: expected [[x,y,z],[x,y,z]] ({exc})") from exc
    if bbox.shape != (2, 3) or not (bbox[0] < bbox[1]).all():
        raise NerfEditError(f"{file}: aabb: expected [[min x,y,z],[max x,y,z]] with min < max")
    return bbox


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
    elif (angle := _lookup(file, meta, frame, "camera_angle_x", where)) is not None:
        blender = 0.5 * w / math.tan(0.5 * angle) if 0.0 < angle < math.pi else math.nan
        if not abs(blender - fx) <= 1e-3 * fx:
            raise NerfEditError(
                f"{file}: {where}: fl_x={fx} (nerfstudio) and camera_angle_x={angle} (Blender, fl_x={blender:.6g} at "
                f"w={w}) disagree: give one intrinsics convention"
            )
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
    mask: torch.Tensor | None = None
    """``(C,H,W)`` bool: the pixels to train on (a capture's masks, pixels that undistortion left without a source);
    None: all of them."""
    points: torch.Tensor | None = None
    """A capture's sparse points ``(P,3)`` float32 in the world frame (the start of primitive fields), or None."""

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def opaque(self) -> bool:
        """Every pixel is covered: no alpha channel, or alpha ≡ 1 (a capture or a scene, not an object on a
        transparent background)."""
        return self.alpha is None or bool((self.alpha >= 1.0).all())

    @property
    def border_coverage(self) -> float:
        """The share of the images' border pixels (one pixel wide, every view) that are covered (alpha ≥ 0.5): 0
        for objects framed whole on a transparent background, large when content (a floor, a table) runs out of
        the frame; 1 for opaque images."""
        if self.alpha is None:
            return 1.0
        covered = self.alpha >= 0.5
        border = torch.cat([covered[:, 0], covered[:, -1], covered[:, 1:-1, 0], covered[:, 1:-1, -1]], dim=1)
        return float(border.float().mean())

    def to(self, device: torch.device | str) -> Dataset:
        alpha = None if self.alpha is None else self.alpha.to(device)
        mask = None if self.mask is None else self.mask.to(device)
        return Dataset(
            self.images.to(device),
            self.cameras.to(device),
            self.split,
            self.image_paths,
            self.background,
            self.scene_bbox.to(device),
            alpha,
            mask,
            None if self.points is None else self.points.to(device),
        )


def load_dataset(
    path: str | os.PathLike, split: str = "train", background=(1.0, 1.0, 1.0), downscale: int = 1
) -> Dataset:
    """Load a Blender or nerfstudio dataset (folder or transforms file) or a COLMAP workspace — see the module
    docstring — with images composited over ``background``, downscaled by an integer ``downscale`` (block averaging)
    and undistorted (:mod:`nerfedit_plugin.data.undistort`); frames that need either are cached
    (:mod:`nerfedit_plugin.data.image_cache`)."""
    background = _background(background)
    if isinstance(downscale, bool) or int(downscale) != downscale or downscale < 1:
        raise NerfEditError(f"downscale: expected a positive integer, got {downscale!r}")
    downscale = int(downscale)
    transforms = read_transforms(path, split)
    cameras = transforms.cameras
    if cameras.width < downscale or cameras.height < downscale:
        raise NerfEditError(f"downscale: factor {downscale} exceeds the image size {cameras.width}x{cameras.height}")
    lenses = transforms.lenses or [None] * len(cameras)
    masks = transforms.mask_paths or [None] * len(cameras)
    images, alphas, valid, any_alpha = [], [], [], False
    for i, (image_path, lens, mask_path) in enumerate(zip(transforms.image_paths, lenses, masks)):
        if not image_path.is_file():
            raise NerfEditError(f"{transforms.file}: frames[{i}].file_path: image {image_path} not found")

        def load(image_path=image_path, lens=lens, mask_path=mask_path) -> dict:
            return _frame_arrays(transforms, image_path, lens, mask_path, background, downscale)

        if lens is None and downscale == 1:
            arrays = load()
        else:
            arrays = cached([image_path, mask_path], (lens, downscale, background), load)
        any_alpha |= bool(arrays["has_alpha"])
        images.append(arrays["rgb"])
        alphas.append(arrays["alpha"])
        valid.append(arrays["valid"])
    cameras = cameras.downscale(downscale)
    bbox = _aabb(transforms.file, transforms.meta) if "aabb" in transforms.meta else estimate_scene_bbox(cameras)
    return Dataset(
        images=torch.from_numpy(np.stack(images)),
        cameras=cameras,
        split=split,
        image_paths=transforms.image_paths,
        background=background,
        scene_bbox=bbox,
        alpha=torch.from_numpy(np.stack(alphas)) if any_alpha else None,
        mask=None if all(v.all() for v in valid) else torch.from_numpy(np.stack(valid)),
        points=None if transforms.points is None else torch.from_numpy(transforms.points.astype(np.float32)),
    )


def _frame_arrays(
    transforms: Transforms, image_path: Path, lens: Lens | None, mask_path: Path | None, background, downscale: int
) -> dict:
    """One frame as loaded: ``rgb`` composited, ``alpha`` (ones without a channel; ``has_alpha``), ``valid`` (the
    mask, and the pixels undistortion could fill), downscaled, then undistorted at the final resolution."""
    cameras = transforms.cameras
    rgb, alpha = read_image(image_path)
    if rgb.shape[:2] != (cameras.height, cameras.width):
        raise NerfEditError(
            f"{image_path}: image is {rgb.shape[1]}x{rgb.shape[0]} but {transforms.file.name} says "
            f"w={cameras.width}, h={cameras.height}"
        )
    valid = np.ones(rgb.shape[:2], np.float32)
    if mask_path is not None:
        if not mask_path.is_file():
            raise NerfEditError(f"{transforms.file}: mask {mask_path} of {image_path.name} not found")
        mask, _ = read_image(mask_path)
        if mask.shape[:2] != rgb.shape[:2]:
            raise NerfEditError(
                f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]} but its image {image_path.name} is "
                f"{rgb.shape[1]}x{rgb.shape[0]}"
            )
        valid = (mask[..., 0] > 0.5).astype(np.float32)
    has_alpha = alpha is not None
    rgb = block_mean(composite(rgb, alpha, background), downscale)
    alpha = block_mean(np.ones(valid.shape, np.float32) if alpha is None else alpha, downscale)
    valid = block_mean(valid, downscale) >= 1.0 - 1e-6  # a pixel is trained on when its whole block is
    if lens is not None:
        lens = lens.scaled(downscale)
        rgb, filled = undistort_image(rgb, lens)
        alpha = undistort_image(alpha, lens)[0]
        valid = undistort_image(valid.astype(np.float32), lens)[0] >= 1.0 - 1e-6
        valid &= filled
    return {"rgb": rgb, "alpha": alpha, "valid": valid, "has_alpha": np.array(has_alpha)}


def _background(background) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in background)
    except (TypeError, ValueError):
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise NerfEditError(f"background: expected 3 numbers in [0, 1], got {background!r}")
    return values
