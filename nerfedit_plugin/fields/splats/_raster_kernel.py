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
    last,
):
    """Front-to-back alpha compositing of each tile's depth-sorted list into ``image (H,W,3)`` (colour before the
    background), ``transmittance (H,W)`` and ``last (H,W)``: one past the position in ``ids`` of the last Gaussian
    composited (the tile's first position when none was; the backward pass starts there). At pixel centre ``p``:
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
        n = np.full((tile, tile), offsets[t], dtype=np.int64)
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
                    n[i, j] = k + 1
        for i in range(y1 - y0):
            for j in range(x1 - x0):
                image[y0 + i, x0 + j, 0] = C[i, j, 0]
                image[y0 + i, x0 + j, 1] = C[i, j, 1]
                image[y0 + i, x0 + j, 2] = C[i, j, 2]
                transmittance[y0 + i, x0 + j] = T[i, j]
                last[y0 + i, x0 + j] = n[i, j]


@numba.njit(parallel=True, cache=True)
def project_forward(
    means, quats, log_scales, logits, sh, rotation, translation, intrinsics, limits, eps2d, antialiased, center,
    means2d, conics, extents, depths, opacities, colors,
):  # fmt: skip
    """The torch path of :mod:`nerfedit_plugin.fields.splats.projection` fused per Gaussian, without autograd: the
    covariance ``(R S)(R S)ᵀ``, the EWA projection (``limits`` = the clamps of ``x/z``, ``y/z``: +x, −x, +y, −y),
    the opacity ``sigmoid(logit)`` (× the antialiasing compensation when ``antialiased``) and the SH colour seen from
    ``center``. Writes ``means2d (N,2)``, ``conics (N,3)``, ``extents (N,2)`` = the dilated ``Σ₂,xx``, ``Σ₂,yy``,
    ``depths (N,)``, ``opacities (N,)`` and ``colors (N,3)``."""
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    k = sh.shape[1]
    for i in numba.prange(len(means)):
        qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        norm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
        r = np.empty((3, 3))
        r[0, 0], r[0, 1], r[0, 2] = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
        r[1, 0], r[1, 1], r[1, 2] = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
        r[2, 0], r[2, 1], r[2, 2] = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
        m = np.empty((3, 3))  # rotation @ R S: the Gaussian's axes in camera space
        for a in range(3):
            for b in range(3):
                m[a, b] = (rotation[a, 0] * r[0, b] + rotation[a, 1] * r[1, b] + rotation[a, 2] * r[2, b]) * np.exp(
                    log_scales[i, b]
                )
        p = np.empty(3)
        for a in range(3):
            p[a] = rotation[a, 0] * means[i, 0] + rotation[a, 1] * means[i, 1] + rotation[a, 2] * means[i, 2]
            p[a] += translation[a]
        z = p[2]
        depths[i] = z
        tx = z * min(max(p[0] / z, -limits[1]), limits[0])
        ty = z * min(max(p[1] / z, -limits[3]), limits[2])
        j = np.empty((2, 3))  # J @ (rotation R S)
        for b in range(3):
            j[0, b] = fx / z * m[0, b] - fx * tx / (z * z) * m[2, b]
            j[1, b] = fy / z * m[1, b] - fy * ty / (z * z) * m[2, b]
        sxx = j[0, 0] * j[0, 0] + j[0, 1] * j[0, 1] + j[0, 2] * j[0, 2]
        sxy = j[0, 0] * j[1, 0] + j[0, 1] * j[1, 1] + j[0, 2] * j[1, 2]
        syy = j[1, 0] * j[1, 0] + j[1, 1] * j[1, 1] + j[1, 2] * j[1, 2]
        raw = sxx * syy - sxy * sxy
        sxx, syy = sxx + eps2d, syy + eps2d
        det = max(sxx * syy - sxy * sxy, 1e-10)
        conics[i, 0], conics[i, 1], conics[i, 2] = syy / det, -sxy / det, sxx / det
        extents[i, 0], extents[i, 1] = sxx, syy
        means2d[i, 0], means2d[i, 1] = fx * p[0] / z + cx, fy * p[1] / z + cy
        opacity = 1.0 / (1.0 + np.exp(-logits[i]))
        if antialiased:
            opacity *= np.sqrt(max(raw / det, 0.0))
        opacities[i] = opacity
        dx, dy, dz = means[i, 0] - center[0], means[i, 1] - center[1], means[i, 2] - center[2]
        length = max(np.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        basis = sh_basis(dx / length, dy / length, dz / length, k)
        for c in range(3):
            value = 0.5
            for q in range(k):
                value += basis[q] * sh[i, q, c]
            colors[i, c] = max(value, 0.0)


@numba.njit(cache=True)
def sh_basis(x, y, z, k):
    """The real SH basis of :func:`nerfedit_plugin.fields.encoding.spherical_harmonics` at one unit direction, its
    first ``k`` (1, 4, 9 or 16) values."""
    out = np.empty(k)
    out[0] = 0.28209479177387814
    if k > 1:
        c1 = 0.4886025119029199
        out[1], out[2], out[3] = -c1 * y, c1 * z, -c1 * x
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        out[4], out[5] = 1.0925484305920792 * x * y, -1.0925484305920792 * y * z
        out[6], out[7] = 0.31539156525252005 * (3.0 * zz - 1.0), -1.0925484305920792 * x * z
        out[8] = 0.5462742152960396 * (xx - yy)
        if k > 9:
            a, b = np.sqrt(35 / (32 * np.pi)), np.sqrt(21 / (32 * np.pi))
            out[9], out[10] = -a * y * (3.0 * xx - yy), np.sqrt(105 / np.pi) / 2 * x * y * z
            out[11], out[12] = -b * y * (4.0 * zz - xx - yy), np.sqrt(7 / np.pi) / 4 * z * (2.0 * zz - 3.0 * (xx + yy))
            out[13], out[14] = -b * x * (4.0 * zz - xx - yy), np.sqrt(105 / np.pi) / 4 * z * (xx - yy)
            out[15] = -a * x * (xx - 3.0 * yy)
    return out
