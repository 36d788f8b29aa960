"""``nerfedit eval``: PSNR, SSIM and LPIPS of a folder of renders against the ground truth
(:func:`~nerfedit_plugin.training.metrics.evaluate_folders`), either side a folder of PNGs or a dataset (its test
images)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from nerfedit_plugin.data.datasets import read_transforms
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import write_text
from nerfedit_plugin.training.metrics import evaluate_folders


def evaluate_images(
    pred: Path, gt: Path, background: tuple[float, float, float], *, json_out: str | os.PathLike | None = None
) -> dict:
    """:func:`~nerfedit_plugin.training.metrics.evaluate_folders` of the image folders ``pred`` and ``gt`` stand for
    (:func:`image_folder`), RGBA images composited on ``background``; also written to ``json_out`` as strict JSON (an
    infinite PSNR — identical images — as null), atomically."""
    result = evaluate_folders(image_folder(pred, "--pred"), image_folder(gt, "--gt"), background)
    if json_out is not None:
        write_text(json_out, json.dumps(_json_numbers(result), indent=2, allow_nan=False))
    return result


def image_folder(path: Path, option: str) -> Path:
    """The folder of PNGs ``path`` stands for: itself when it holds PNGs (e.g. a `nerfedit render` folder, whose
    config.yml is ignored), else a dataset's test images (`nerfedit generate --out`: the cameras `nerfedit render
    --cameras DATASET` renders). An animated render (frame_NNNN folders) is an error naming a frame folder."""
    if not path.is_dir() or any(path.glob("*.png")):
        return path
    frames = sorted(p for p in path.glob("frame_[0-9]*") if p.is_dir())
    if frames:
        raise NerfEditError(f"{option} {path}: an animated render; compare one frame, e.g. {option} {frames[0]}")
    try:
        folders = {p.parent for p in read_transforms(path, "test").image_paths}
    except NerfEditError:
        return path
    return folders.pop() if len(folders) == 1 else path


def _json_numbers(value):
    """``value`` with non-finite floats as None: JSON has no inf (the PSNR of identical images) or NaN."""
    if isinstance(value, dict):
        return {k: _json_numbers(v) for k, v in value.items()}
    return None if isinstance(value, float) and not math.isfinite(value) else value
