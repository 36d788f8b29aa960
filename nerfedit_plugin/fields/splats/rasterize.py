r"""The CPU rasteriser of projected Gaussians: cull, depth sort, tile lists, front-to-back compositing (numba).

For each pixel centre ``p`` the Gaussians are taken in increasing view depth (ties in index order) and composited
front to back: ``α_i = min(0.99, o_i exp(−½ dᵀ Σ₂⁻¹ d))``, ``d = p − μ₂``, Gaussians with ``α_i < 1/255`` skipped,
``C = Σ_i c_i α_i T_i``, ``T_{i+1} = T_i (1 − α_i)``, and the pixel stops before the Gaussian that would take ``T``
below ``10⁻⁴``; the image is ``C + T · background``.

Exactness of the culling: ``α ≥ 1/255`` needs ``½ dᵀ Σ₂⁻¹ d ≤ τ = ln(255 o)``, an ellipse whose bounding box has the
half sides ``√(2τ Σ₂,xx)``, ``√(2τ Σ₂,yy)``; each Gaussian visits the pixel centres in that box (grown by a hair for
rounding) and the 16×16 tiles it touches, so culling drops nothing the per-pixel rule would keep. Gaussians at view
depth ≤ ``NEAR`` or with ``o < 1/255`` are never drawn.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from nerfedit_plugin.fields.splats import _raster_kernel
from nerfedit_plugin.fields.splats.projection import EPS2D, NEAR, frustum_limits, view_matrix
from nerfedit_plugin.geometry.launch import launch

TILE = 16
"""Tile side in pixels."""
MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
MIN_TRANSMITTANCE = 1e-4
_MARGIN = (1.0 + 1e-4, 1e-3)
"""Culling boxes are grown to ``ext · 1.0001 + 0.001`` pixels: beyond the float32 rounding of α near 1/255."""


@dataclass
class RasterStats:
    """What one rasterisation did: Gaussians drawn, tile-list entries, seconds per stage."""

    visible: int = 0
    intersections: int = 0
    seconds: dict[str, float] = field(default_factory=dict)


def pixel_rects(
    means2d: np.ndarray, variances: np.ndarray, opacities: np.ndarray, depths: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(visible (N,) bool, rect (N,4) int32)``: the inclusive pixel box ``(x0, y0, x1, y1)`` of each Gaussian's
    ``α ≥ 1/255`` ellipse clipped to the image (module docstring); invisible ones are behind ``NEAR``, too faint, or
    off the image."""
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.log(np.maximum(opacities.astype(np.float64), 1e-30) / MIN_ALPHA)
        visible = (depths > NEAR) & (opacities >= MIN_ALPHA) & np.isfinite(means2d).all(1)
        tau = np.where(visible, tau, 0.0)
        extent = np.sqrt(2.0 * tau[:, None] * variances.astype(np.float64))
        extent = extent * _MARGIN[0] + _MARGIN[1]
        centre = np.where(visible[:, None], means2d.astype(np.float64), 0.0)
        limit = np.array([width - 1, height - 1], dtype=np.float64)
        low = np.clip(np.ceil(centre - extent - 0.5), -1, limit + 1)
        high = np.clip(np.floor(centre + extent - 0.5), -1, limit + 1)
    visible &= np.isfinite(extent).all(1) & (high >= 0).all(1) & (low <= limit).all(1) & (low <= high).all(1)
    low, high = np.clip(low, 0, limit), np.clip(high, 0, limit)
    return visible, np.concatenate([low, high], 1).astype(np.int32)


class Tiles(NamedTuple):
    """The depth-sorted tile lists of one view: tile ``t`` holds ``ids[offsets[t]:offsets[t + 1]]``; ``rect (N,4)``
    each Gaussian's pixel box; ``tiles_x`` tiles per row."""

    offsets: np.ndarray
    ids: np.ndarray
    rect: np.ndarray
    tiles_x: int


def tile_lists(
    means2d: np.ndarray,
    variances: np.ndarray,
    opacities: np.ndarray,
    depths: np.ndarray,
    width: int,
    height: int,
    stats: RasterStats,
) -> Tiles:
    """Cull (:func:`pixel_rects`), sort by depth (ties by index) and bin into 16×16 tiles by one counting sort."""
    start = time.perf_counter()
    visible, rect = pixel_rects(means2d, variances, opacities, depths, width, height)
    stats.seconds["cull"] = time.perf_counter() - start
    start = time.perf_counter()
    index = np.flatnonzero(visible)
    order = index[np.argsort(depths[index], kind="stable")].astype(np.int64)
    stats.seconds["sort"] = time.perf_counter() - start
    start = time.perf_counter()
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    offsets, ids = _raster_kernel.tile_lists(order, np.ascontiguousarray(rect // TILE), tiles_x, tiles_x * tiles_y)
    stats.seconds["tiles"] = time.perf_counter() - start
    stats.visible, stats.intersections = len(order), int(offsets[-1])
    return Tiles(offsets, ids, rect, tiles_x)


def composite(
    tiles: Tiles,
    means2d: np.ndarray,
    conics: np.ndarray,
    colors: np.ndarray,
    opacities: np.ndarray,
    width: int,
    height: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Front-to-back compositing of float32 arrays over ``tiles`` → ``(colour (H,W,3) before the background,
    transmittance (H,W), last (H,W))``, ``last`` one past each pixel's last composited entry of ``tiles.ids``."""
    image = np.zeros((height, width, 3), dtype=np.float32)
    transmittance = np.ones((height, width), dtype=np.float32)
    last = np.zeros((height, width), dtype=np.int64)
    launch(
        _raster_kernel.composite,
        tiles.offsets,
        tiles.ids,
        means2d,
        conics,
        colors,
        opacities,
        tiles.rect,
        width,
        height,
        TILE,
        tiles.tiles_x,
        np.float32(MIN_ALPHA),
        np.float32(MAX_ALPHA),
        np.float32(MIN_TRANSMITTANCE),
        image,
        transmittance,
        last,
    )
    return image, transmittance, last


def as_float32(t: torch.Tensor) -> np.ndarray:
    """A contiguous float32 numpy copy of ``t`` (detached, on the CPU)."""
    return np.ascontiguousarray(t.detach().cpu().numpy(), dtype=np.float32)


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
    """Composite projected Gaussians (``(N,2)``, ``(N,3)`` conics, ``(N,2)`` the diagonal of Σ₂, ``(N,3)`` colours,
    ``(N,)`` opacities in [0, 1], ``(N,)`` view depths) → ``(image (H,W,3), transmittance (H,W))`` float32 on the
    CPU, no autograd (module docstring). ``stats`` receives the counts and stage times."""
    stats = RasterStats() if stats is None else stats
    mu, conic, rgb, opacity = (as_float32(t) for t in (means2d, conics, colors, opacities))
    variances, depths = variances.detach().cpu().numpy(), depths.detach().cpu().numpy()
    tiles = tile_lists(mu, variances, opacity, depths, width, height, stats)
    start = time.perf_counter()
    image, transmittance, _ = composite(tiles, mu, conic, rgb, opacity, width, height)
    image += transmittance[:, :, None] * np.asarray(background, dtype=np.float32)
    stats.seconds["composite"] = time.perf_counter() - start
    return torch.from_numpy(image), torch.from_numpy(transmittance)


def project_gaussians(
    means: np.ndarray,
    quats: np.ndarray,
    log_scales: np.ndarray,
    logits: np.ndarray,
    sh: np.ndarray,
    c2w: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    width: int,
    height: int,
    antialiased: bool = False,
) -> tuple[torch.Tensor, ...]:
    """The projection, opacity and colour of :mod:`.projection` in one compiled pass (no autograd) for the OpenGL
    camera ``c2w (4,4)`` → ``(means2d, conics, variances, colors, opacities, depths)`` as float32 tensors, the
    arguments of :func:`rasterize`."""
    rotation, translation = (t.numpy().astype(np.float64) for t in view_matrix(torch.as_tensor(c2w).double()))
    n = len(means)
    out = [np.empty((n, 2)), np.empty((n, 3)), np.empty((n, 2)), np.empty(n), np.empty(n), np.empty((n, 3))]
    launch(
        _raster_kernel.project_forward,
        *(np.ascontiguousarray(a, dtype=np.float64) for a in (means, quats, log_scales, logits, sh)),
        rotation,
        translation,
        np.asarray(intrinsics, dtype=np.float64),
        np.asarray(frustum_limits(intrinsics, width, height), dtype=np.float64),
        EPS2D,
        antialiased,
        np.asarray(c2w, dtype=np.float64)[:3, 3].copy(),
        *out,
    )
    means2d, conics, variances, depths, opacities, colors = (torch.from_numpy(a.astype(np.float32)) for a in out)
    return means2d, conics, variances, colors, opacities, depths
