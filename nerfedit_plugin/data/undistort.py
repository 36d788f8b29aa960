"""Undistorting images once, so the rest of nerfedit sees pinhole cameras only.

The output image keeps the lens's ``fx, fy, cx, cy`` and size and drops its distortion: output pixel centre ``p``
has normalised coordinates ``n = K⁻¹ p``; its colour is the input bilinearly sampled at ``K · distort(n)``
(:meth:`nerfedit_plugin.data.lens.Lens.distort`, exact, no iterative inversion). Pixels whose source falls outside
the input image are not valid (barrel distortion leaves such corners): the loader keeps them out of training through
the dataset's mask.
"""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.data.lens import Lens


def undistort_image(image: np.ndarray, lens: Lens) -> tuple[np.ndarray, np.ndarray]:
    """``(image (H,W,C), valid (H,W) bool)``: ``image (H,W,C)`` or ``(H,W)`` resampled as a pinhole image of the same
    intrinsics (see the module docstring); a 2-D input gives a 2-D output."""
    from scipy.ndimage import map_coordinates

    height, width = image.shape[:2]
    ys, xs = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    source = lens.distort(lens.pixel_to_normalized(np.stack([xs, ys], axis=-1)))
    sx, sy = lens.fx * source[..., 0] + lens.cx - 0.5, lens.fy * source[..., 1] + lens.cy - 0.5  # array indices
    valid = (sx >= -0.5) & (sx <= width - 0.5) & (sy >= -0.5) & (sy <= height - 0.5)
    planes = image[..., None] if image.ndim == 2 else image
    out = np.stack(
        [map_coordinates(planes[..., c], [sy, sx], order=1, mode="nearest") for c in range(planes.shape[-1])],
        axis=-1,
    ).astype(image.dtype)
    return (out[..., 0] if image.ndim == 2 else out), valid
