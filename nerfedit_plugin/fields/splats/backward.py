r"""The rasteriser with gradients: :func:`rasterize` as a torch autograd function on the CPU.

Forward: the tile compositor of :mod:`.rasterize` (the same culling, sort and compositing, so training sees exactly
what is rendered). Backward: the numba kernel :func:`._backward_kernel.composite_backward` (the gradient w.r.t. the
2D means, conics, colours and opacities, as gsplat's ``rasterize_to_pixels`` backward), summed over each Gaussian's
tile-list entries. Everything before (covariances, the EWA projection, SH colours: :mod:`.projection`) is torch, so
autograd carries the gradient to the Gaussians' parameters. Culling is not differentiated: the pixel boxes depend on
the variances and depths, which only decide where a Gaussian is evaluated.
"""

from __future__ import annotations

import numpy as np
import torch

from nerfedit_plugin.fields.splats import _backward_kernel
from nerfedit_plugin.fields.splats.rasterize import (
    MAX_ALPHA,
    MIN_ALPHA,
    TILE,
    RasterStats,
    as_float32,
    composite,
    tile_lists,
)
from nerfedit_plugin.geometry.launch import launch


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, variances, depths, width, height, background, stats):
        mu, conic, rgb, opacity = (as_float32(t) for t in (means2d, conics, colors, opacities))
        tiles = tile_lists(
            mu, variances.detach().cpu().numpy(), opacity, depths.detach().cpu().numpy(), width, height, stats
        )
        image, transmittance, last = composite(tiles, mu, conic, rgb, opacity, width, height)
        bg = np.asarray(background, dtype=np.float32)
        image += transmittance[:, :, None] * bg
        ctx.arrays = (tiles, mu, conic, rgb, opacity, transmittance, last, bg, width, height)
        ctx.n = len(mu)
        out = torch.from_numpy(transmittance).to(means2d.device)
        ctx.mark_non_differentiable(out)
        return torch.from_numpy(image).to(means2d.device), out

    @staticmethod
    def backward(ctx, grad_image, grad_transmittance):
        tiles, mu, conic, rgb, opacity, transmittance, last, bg, width, height = ctx.arrays
        grad = np.ascontiguousarray(grad_image.detach().cpu().numpy(), dtype=np.float32)
        m = len(tiles.ids)
        parts = [np.zeros((m, 2), np.float32), np.zeros((m, 3), np.float32), np.zeros((m, 3), np.float32)]
        parts.append(np.zeros(m, np.float32))
        launch(
            _backward_kernel.composite_backward,
            tiles.offsets,
            tiles.ids,
            mu,
            conic,
            rgb,
            opacity,
            tiles.rect,
            width,
            height,
            TILE,
            tiles.tiles_x,
            np.float32(MIN_ALPHA),
            np.float32(MAX_ALPHA),
            transmittance,
            last,
            bg,
            grad,
            *parts,
        )
        device = grad_image.device
        sums = [_per_gaussian(tiles.ids, part, ctx.n).to(device) for part in parts]
        return sums[0], sums[1], sums[2], sums[3][:, 0], None, None, None, None, None, None


def _per_gaussian(ids: np.ndarray, values: np.ndarray, n: int) -> torch.Tensor:
    """``(n, C)`` float32: the rows of ``values (M, C)`` (or ``(M,)``) summed by Gaussian ``ids (M,)``."""
    values = values.reshape(len(ids), -1)
    columns = [np.bincount(ids, weights=values[:, c], minlength=n) for c in range(values.shape[1])]
    return torch.from_numpy(np.stack(columns, 1).astype(np.float32))


def rasterize(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    variances: torch.Tensor,
    colors: torch.Tensor,
    opacities: torch.Tensor,
    depths: torch.Tensor,
    width: int,
    height: int,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    stats: RasterStats | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`nerfedit_plugin.fields.splats.rasterize.rasterize` (same arguments, same image) with gradients of the
    image w.r.t. ``means2d (N,2)``, ``conics (N,3)``, ``colors (N,3)`` and ``opacities (N,)`` (float32; the
    transmittance it also returns is not differentiable)."""
    stats = RasterStats() if stats is None else stats
    return _Rasterize.apply(
        means2d, conics, colors, opacities, variances, depths, width, height, tuple(background), stats
    )
