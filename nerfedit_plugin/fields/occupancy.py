"""Occupancy grid: a coarse boolean mask of the cells of a box where a field may be non-empty.

The renderer drops samples whose canonical position lies in an unoccupied cell (the ``Field.occupied`` hook), so
rays cost little where the scene is empty. The grid is conservative by construction when it is updated from an
*upper bound* of the density in each cell: a cell is marked empty only if its bound is at most ``threshold``
(optionally dilated so that empty cells next to occupied ones keep receiving gradients while training).
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F


def cell_maxima(values: torch.Tensor, cells: int) -> torch.Tensor:
    """Exact maximum of a trilinear interpolant over each of ``cells³`` equal cells: ``values (N+1, N+1, N+1)`` at
    the vertices of ``N³`` grid cells (``cells`` divides ``N``) → ``(cells,)*3``, the maximum of the vertex values of
    each cell (interpolation is multilinear, so it never exceeds them)."""
    k = (values.shape[0] - 1) // cells
    return F.max_pool3d(values[None, None], kernel_size=k + 1, stride=k)[0, 0]


def silhouette_depths(coverage: torch.Tensor) -> torch.Tensor:
    """Free depths (:meth:`OccupancyGrid.carve`) of silhouettes ``coverage (C,H,W)`` bool: a covered pixel's ray may
    meet the object anywhere (0), an uncovered one's is empty all along (``inf``)."""
    return torch.where(coverage, 0.0, torch.inf)


class OccupancyGrid(torch.nn.Module):
    """``R³`` equal cells (``R`` ≤ 256) over ``bbox (2,3)``; starts all occupied. Points outside the box are
    unoccupied."""

    def __init__(self, bbox: torch.Tensor, resolution: int) -> None:
        super().__init__()
        if not 1 <= resolution <= 256:
            raise ValueError(f"OccupancyGrid: resolution must be in [1, 256], got {resolution}")
        self.resolution = int(resolution)
        self.register_buffer("bbox", torch.as_tensor(bbox, dtype=torch.float32).reshape(2, 3).clone())
        self.register_buffer("mask", torch.ones((resolution,) * 3, dtype=torch.bool))
        self.register_buffer("hull", torch.ones((resolution,) * 3, dtype=torch.bool))  # cells kept by carve()

    def occupied(self, points: torch.Tensor) -> torch.Tensor:
        """``(M,)`` bool: the point lies in the box and in an occupied cell (cells are closed on the low side)."""
        lo, hi = self.bbox
        r = self.resolution
        u = (points - lo) * (r / (hi - lo))
        inside = (u.amin(-1) >= 0) & (u.amax(-1) <= r)
        strides = torch.tensor([r * r, r, 1.0], dtype=u.dtype, device=u.device)  # exact in float32 (r³ < 2²⁴)
        flat = (u.floor_().clamp_(0, r - 1) @ strides).long()
        return self.mask.view(-1).index_select(0, flat) & inside

    @torch.no_grad()
    def update(self, cell_bound: torch.Tensor, threshold: float, dilation: int = 0, shell: int = 0) -> None:
        """Occupied ⇔ ``cell_bound > threshold`` (``cell_bound (R,R,R)``: an upper bound of the density in each
        cell), grown by ``dilation`` cells in every direction (a ``(2d+1)³`` max filter), within the carved hull.

        ``shell > 0`` also empties the deep interior: occupied cells more than ``shell`` cells (Chebyshev) from
        any free cell. Rays reach them only through at least ``shell`` occupied cells, so a field trained with
        this grid learns an opaque shell and never needs the interior.
        """
        if cell_bound.shape != self.mask.shape:
            raise ValueError(
                f"OccupancyGrid.update: expected bounds of shape {tuple(self.mask.shape)}, "
                f"got {tuple(cell_bound.shape)}"
            )
        dense = (cell_bound > threshold).float()[None, None]
        mask = F.max_pool3d(dense, 2 * dilation + 1, stride=1, padding=dilation) > 0 if dilation > 0 else dense > 0
        if shell > 0:
            free = F.pad(1.0 - dense, (shell,) * 6, value=1.0)  # outside the box counts as free
            mask &= F.max_pool3d(free, 2 * shell + 1, stride=1) > 0
        self.mask.copy_(mask[0, 0] & self.hull)

    @torch.no_grad()
    def carve(self, cameras: Any, free: torch.Tensor, margin: int = 2, keep_unseen: bool = True) -> None:
        """Space carving: mark empty every cell that, in some camera, lies wholly in front of what the pixels within
        ``margin`` pixels of its centre's projection see — ``free (C,H,W)``, the camera-space depth up to which each
        pixel's ray is known to be empty (:func:`silhouette_depths`: ``inf`` off an object's silhouette, 0 on it, for
        the visual hull; a photometric hull gives where a layer is seen). A cell is in front when its centre's depth
        plus its half diagonal is below the smallest ``free`` there. Points inside an object lie behind every ray
        that sees it, so with ``margin`` ≥ the projected half-diagonal of a cell no cell containing the object is
        carved. Cells outside a camera's image are kept (``keep_unseen=False``: carved — what remains is seen by every
        camera).
        """
        lo, hi = self.bbox
        r = self.resolution
        axes = [lo[d] + (torch.arange(r, device=lo.device) + 0.5) * (hi[d] - lo[d]) / r for d in range(3)]
        centres = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
        radius = float(((hi - lo) / r).norm()) / 2
        nearest = -F.max_pool2d(-free.float()[:, None], 2 * margin + 1, stride=1, padding=margin)[:, 0]
        keep = torch.ones(len(centres), dtype=torch.bool, device=lo.device)
        w2c = torch.linalg.inv(cameras.c2w.to(lo.device))
        for i in range(len(cameras)):
            local = centres @ w2c[i, :3, :3].T + w2c[i, :3, 3]  # OpenGL camera space: looking down −z
            depth = -local[:, 2]
            x = cameras.fx[i] * local[:, 0] / depth + cameras.cx[i]
            y = -cameras.fy[i] * local[:, 1] / depth + cameras.cy[i]
            seen = (depth > 0) & (x >= 0) & (x < cameras.width) & (y >= 0) & (y < cameras.height)
            col = x.clamp(0, cameras.width - 1).long()
            row = y.clamp(0, cameras.height - 1).long()
            keep &= (~seen & keep_unseen) | (seen & (depth + radius >= nearest[i, row, col]))
        self.hull &= keep.reshape(r, r, r)
        self.mask &= self.hull

    @property
    def fraction(self) -> float:
        """Fraction of occupied cells."""
        return float(self.mask.float().mean())
