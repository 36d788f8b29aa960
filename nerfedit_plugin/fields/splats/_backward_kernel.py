"""numba kernel of the rasteriser's backward pass: the gradient of the tile compositor, per tile-list entry.

Private: :mod:`nerfedit_plugin.fields.splats.backward` calls it with the forward pass's arrays.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(parallel=True, cache=True)
def composite_backward(
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
    transmittance,
    last,
    background,
    grad_image,
    grad_means2d,
    grad_conics,
    grad_colors,
    grad_opacities,
):
    """The gradient of ``C = Σ_i c_i α_i T_i + T_N · background`` (the compositor of ``_raster_kernel.composite``)
    with ``G = ∂L/∂C`` = ``grad_image (H,W,3)``, written per entry ``k`` of the tile lists ``ids`` (each entry belongs
    to one tile, so tiles run in parallel without sharing a row): ``grad_means2d (M,2)``, ``grad_conics (M,3)``,
    ``grad_colors (M,3)``, ``grad_opacities (M,)``.

    Each pixel walks its list back from ``last`` (one past its last composited entry) with ``T_N`` =
    ``transmittance``, recovering ``T_i = T_{i+1} / (1 − α_i)`` and the light behind ``i``,
    ``B_i = G · (Σ_{j>i} c_j α_j T_j + T_N background)``:
    ``∂L/∂c_i = α_i T_i G``, ``∂L/∂α_i = T_i (G · c_i) − B_i / (1 − α_i)``; through
    ``α = o exp(p)`` (zero where α was clamped to ``max_alpha``), ``p = −½(a dx² + c dy²) − b dx dy``,
    ``d = pixel centre − μ₂``: ``∂α/∂o = exp p``, ``∂α/∂p = α``, ``∂p/∂μ₂ = (a dx + b dy, b dx + c dy)``,
    ``∂p/∂(a, b, c) = (−½ dx², −dx dy, −½ dy²)``. Entries the forward pass skipped (``α < min_alpha``, ``p > 0``,
    pixels outside the entry's ``pixel_rect``) get nothing from that pixel."""
    n_tiles = len(offsets) - 1
    one = np.float32(1.0)
    half = np.float32(0.5)
    for t in numba.prange(n_tiles):
        x0 = (t % tiles_x) * tile
        y0 = (t // tiles_x) * tile
        x1 = min(x0 + tile, width)
        y1 = min(y0 + tile, height)
        for py in range(y0, y1):
            for px in range(x0, x1):
                gr, gg, gb = grad_image[py, px, 0], grad_image[py, px, 1], grad_image[py, px, 2]
                T = transmittance[py, px]
                behind = T * (gr * background[0] + gg * background[1] + gb * background[2])
                fx = np.float32(px) + half
                fy = np.float32(py) + half
                for k in range(last[py, px] - 1, offsets[t] - 1, -1):
                    g = ids[k]
                    if px < pixel_rect[g, 0] or px > pixel_rect[g, 2] or py < pixel_rect[g, 1] or py > pixel_rect[g, 3]:
                        continue
                    a, b, c = conics[g, 0], conics[g, 1], conics[g, 2]
                    dx = fx - means2d[g, 0]
                    dy = fy - means2d[g, 1]
                    power = np.float32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
                    if power > 0:
                        continue
                    gauss = np.exp(power)
                    raw = opacities[g] * gauss
                    alpha = min(max_alpha, raw)
                    if alpha < min_alpha:
                        continue
                    T = T / (one - alpha)
                    weight = alpha * T
                    grad_colors[k, 0] += weight * gr
                    grad_colors[k, 1] += weight * gg
                    grad_colors[k, 2] += weight * gb
                    shade = gr * colors[g, 0] + gg * colors[g, 1] + gb * colors[g, 2]
                    grad_alpha = T * shade - behind / (one - alpha)
                    behind += weight * shade
                    if raw >= max_alpha:
                        continue
                    grad_opacities[k] += grad_alpha * gauss
                    grad_power = grad_alpha * alpha
                    grad_means2d[k, 0] += grad_power * (a * dx + b * dy)
                    grad_means2d[k, 1] += grad_power * (b * dx + c * dy)
                    grad_conics[k, 0] += -half * grad_power * dx * dx
                    grad_conics[k, 1] += -grad_power * dx * dy
                    grad_conics[k, 2] += -half * grad_power * dy * dy
