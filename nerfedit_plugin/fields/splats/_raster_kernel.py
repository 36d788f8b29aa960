"""numba kernels of the CPU rasteriser: tile lists by a counting sort, front-to-back compositing per 16×16 tile.

Private: :mod:`nerfedit_plugin.fields.splats.rasterize` calls them with checked, contiguous arrays.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def tile_lists(order, tile_rect, tiles_x, n_tiles):
    """Counting sort of Gaussians into the tiles their rectangle ``tile_rect[g] = (x0, y0, x1, y1)`` (inclusive tile
    indices) covers, in the sequence ``order`` (front to back), so every tile's list is depth-sorted →
    ``(offsets (n_tiles + 1,), ids)``: tile ``t`` holds ``ids[offsets[t]:offsets[t + 1]]``."""
    counts = np.zeros(n_tiles + 1, dtype=np.int64)
    for g in order:
        for ty in range(tile_rect[g, 1], tile_rect[g, 3] + 1):
            for tx in range(tile_rect[g, 0], tile_rect[g, 2] + 1):
                counts[ty * tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    fill = offsets[:-1].copy()
    ids = np.empty(offsets[-1], dtype=np.int32)
    for g in order:
        for ty in range(tile_rect[g, 1], tile_rect[g, 3] + 1):
            for tx in range(tile_rect[g, 0], tile_rect[g, 2] + 1):
                t = ty * tiles_x + tx
                ids[fill[t]] = g
                fill[t] += 1
    return offsets, ids


@numba.njit(parallel=True, cache=True)
def composite(
    offsets,
    ids,
    means2d,
    conics,
    colors,
    opacities,
    pixel_rect,
    width,
    height,
    tile,
    tiles_x,
    min_alpha,
    max_alpha,
    min_transmittance,
    image,
    transmittance,
    count,
):
    """Front-to-back alpha compositing of each tile's depth-sorted list into ``image (H,W,3)`` (colour before the
    background), ``transmittance (H,W)`` and ``count (H,W)`` (Gaussians composited). At pixel centre ``p``:
    ``α = min(max_alpha, o exp(−½ dᵀ Σ₂⁻¹ d))``, ``d = p − μ₂``, skipped below ``min_alpha``; a pixel stops before the
    Gaussian that would take its transmittance below ``min_transmittance``. Each Gaussian visits only its pixel
    rectangle ``pixel_rect[g] = (x0, y0, x1, y1)`` (inclusive) within the tile."""
    n_tiles = len(offsets) - 1
    for t in numba.prange(n_tiles):
        x0 = (t % tiles_x) * tile
        y0 = (t // tiles_x) * tile
        x1 = min(x0 + tile, width)
        y1 = min(y0 + tile, height)
        T = np.ones((tile, tile), dtype=np.float32)
        C = np.zeros((tile, tile, 3), dtype=np.float32)
        n = np.zeros((tile, tile), dtype=np.int32)
        done = np.zeros((tile, tile), dtype=np.bool_)
        remaining = (x1 - x0) * (y1 - y0)
        for k in range(offsets[t], offsets[t + 1]):
            if remaining == 0:
                break
            g = ids[k]
            mx, my = means2d[g, 0], means2d[g, 1]
            a, b, c = conics[g, 0], conics[g, 1], conics[g, 2]
            o = opacities[g]
            for py in range(max(pixel_rect[g, 1], y0), min(pixel_rect[g, 3] + 1, y1)):
                dy = np.float32(py) + np.float32(0.5) - my
                for px in range(max(pixel_rect[g, 0], x0), min(pixel_rect[g, 2] + 1, x1)):
                    i, j = py - y0, px - x0
                    if done[i, j]:
                        continue
                    dx = np.float32(px) + np.float32(0.5) - mx
                    power = np.float32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
                    if power > 0:
                        continue
                    alpha = min(max_alpha, o * np.exp(power))
                    if alpha < min_alpha:
                        continue
                    next_t = T[i, j] * (np.float32(1.0) - alpha)
                    if next_t < min_transmittance:
                        done[i, j] = True
                        remaining -= 1
                        continue
                    w = alpha * T[i, j]
                    C[i, j, 0] += w * colors[g, 0]
                    C[i, j, 1] += w * colors[g, 1]
                    C[i, j, 2] += w * colors[g, 2]
                    T[i, j] = next_t
                    n[i, j] += 1
        for i in range(y1 - y0):
            for j in range(x1 - x0):
                image[y0 + i, x0 + j, 0] = C[i, j, 0]
                image[y0 + i, x0 + j, 1] = C[i, j, 1]
                image[y0 + i, x0 + j, 2] = C[i, j, 2]
                transmittance[y0 + i, x0 + j] = T[i, j]
                count[y0 + i, x0 + j] = n[i, j]
