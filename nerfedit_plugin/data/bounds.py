"""The foreground box of a capture: where the field's grid lives and the mesh is extracted.

From sparse points when there are enough: a point belongs to the foreground when it lies inside the view frustum of
at least :data:`VIEW_FRACTION` of the cameras (what most views look at, not the far background one camera grazes);
the box spans the :data:`QUANTILE`…(1 − :data:`QUANTILE`) quantiles of those points per axis (robust to stray
points); a side shorter than :data:`MIN_SIDE` × the longest grows to it towards the cameras (objects on a floor:
SIFT finds the textured floor, the objects stand up from it towards the cameras); then the box grows by
:data:`MARGIN` of its size on every side. Otherwise from the frustums alone:
:func:`estimate_scene_bbox`, a ball every camera sees whole.
"""

from __future__ import annotations

import numpy as np
import torch

from nerfedit_plugin.data.cameras import Cameras

VIEW_FRACTION = 0.5
QUANTILE = 0.01
MARGIN = 0.1
MIN_SIDE = 0.5
MIN_POINTS = 20
"""Fewer foreground points than this: the frustum estimate is used instead."""


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


def in_view_counts(cameras: Cameras, points: np.ndarray) -> np.ndarray:
    """``(P,)`` how many of the (pinhole) cameras have each point ``(P,3)`` in front and inside their image."""
    c2w = cameras.c2w.double().cpu().numpy()
    counts = np.zeros(len(points), dtype=np.int64)
    for i in range(len(cameras)):
        local = (points - c2w[i, :3, 3]) @ c2w[i, :3, :3]  # OpenGL camera frame: looks down −z
        depth = -local[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = float(cameras.fx[i]) * local[:, 0] / depth + float(cameras.cx[i])
            y = -float(cameras.fy[i]) * local[:, 1] / depth + float(cameras.cy[i])
        counts += (depth > 0) & (x >= 0) & (x <= cameras.width) & (y >= 0) & (y <= cameras.height)
    return counts


def foreground_box(cameras: Cameras, points: np.ndarray | None = None) -> np.ndarray:
    """``(2,3)`` float64 [min, max] in the cameras' frame: from ``points`` when enough are in the foreground, else
    from the frustums (see the module docstring)."""
    if points is not None and len(points):
        points = np.asarray(points, dtype=np.float64)
        foreground = points[in_view_counts(cameras, points) >= VIEW_FRACTION * len(cameras)]
        if len(foreground) >= MIN_POINTS:
            low, high = np.quantile(foreground, [QUANTILE, 1.0 - QUANTILE], axis=0)
            short = np.maximum(MIN_SIDE * (high - low).max() - (high - low), 0.0)
            towards = cameras.c2w[:, :3, 3].double().cpu().numpy().mean(0) > (low + high) / 2
            high, low = high + np.where(towards, short, 0.0), low - np.where(towards, 0.0, short)
            margin = MARGIN * (high - low).max()
            return np.stack([low - margin, high + margin])
    return estimate_scene_bbox(cameras).double().cpu().numpy()
