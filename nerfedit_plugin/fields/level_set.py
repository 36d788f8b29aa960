"""Mesh extraction shared by the trained field backends: marching cubes (scikit-image) of a scalar field sampled on
a lattice over the scene box, with vertex colours queried from the field."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from nerfedit_plugin.geometry.mesh import SurfaceMesh

CHUNK = 1 << 18
"""Points queried at once."""


@torch.no_grad()
def extract_level_set(
    scalar: Callable[[torch.Tensor], torch.Tensor],
    color: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    bbox: torch.Tensor,
    resolution: int,
    level: float,
) -> SurfaceMesh:
    """The surface ``scalar(x) = level`` inside ``bbox (2,3)``, with ``scalar`` larger inside the object (density,
    or minus a signed distance): marching cubes of ``scalar`` sampled on ``resolution³`` lattice points spanning
    the box. Faces wind counter-clockwise seen from outside; vertex colours are ``color(x, d)`` at each vertex seen
    along the inward normal ``d``. A level outside the sampled range raises ValueError."""
    from skimage.measure import marching_cubes

    lo, hi = bbox
    axes = [torch.linspace(float(lo[d]), float(hi[d]), resolution, device=lo.device) for d in range(3)]
    lattice = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    volume = torch.cat([scalar(chunk) for chunk in lattice.split(CHUNK)]).reshape((resolution,) * 3).cpu().numpy()
    if not volume.min() < level < volume.max():
        raise ValueError(
            f"extract_mesh: level {level} is outside the range [{volume.min():.3g}, {volume.max():.3g}] of the field"
        )
    spacing = ((hi - lo) / (resolution - 1)).cpu().numpy()
    vertices, faces, normals, _ = marching_cubes(volume, level, spacing=tuple(spacing.tolist()))
    vertices = vertices + lo.cpu().numpy()
    inward = -torch.from_numpy(np.ascontiguousarray(normals)).float().to(lo.device)  # skimage: outward
    points = torch.from_numpy(vertices).float().to(lo.device)
    colors = torch.cat([color(p, d) for p, d in zip(points.split(CHUNK), inward.split(CHUNK))])
    return SurfaceMesh(
        vertices.astype(np.float64), faces[:, ::-1].astype(np.int64), colors.cpu().numpy().astype(np.float64)
    )
