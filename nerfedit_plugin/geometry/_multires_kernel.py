"""Compiled (numba) kernel of :mod:`nerfedit_plugin.geometry.multires`: the fine surface carried by the coarse one.
It runs through :func:`~nerfedit_plugin.geometry.launch.launch`."""

from __future__ import annotations

from numba import njit, prange


@njit(cache=True, parallel=True)
def carry(points, corners, weights, coarse_rest, coarse_moved, rotations, out):
    """points (V,3), corners (V,3) int64, weights (V,3), coarse_rest (C,3), coarse_moved (C,3), rotations (C,3,3)
    (any linear maps) → out (V,3): ``out_i = Σ_c w_ic (y_k + R_k (p_i − q_k))``, ``k = corners[i, c]`` (terms of
    weight 0 skipped)."""
    for i in prange(len(points)):
        a0 = a1 = a2 = 0.0
        for c in range(3):
            w = weights[i, c]
            if w == 0.0:
                continue
            k = corners[i, c]
            d0 = points[i, 0] - coarse_rest[k, 0]
            d1 = points[i, 1] - coarse_rest[k, 1]
            d2 = points[i, 2] - coarse_rest[k, 2]
            r = rotations[k]
            a0 += w * (coarse_moved[k, 0] + (r[0, 0] * d0 + r[0, 1] * d1 + r[0, 2] * d2))
            a1 += w * (coarse_moved[k, 1] + (r[1, 0] * d0 + r[1, 1] * d1 + r[1, 2] * d2))
            a2 += w * (coarse_moved[k, 2] + (r[2, 0] * d0 + r[2, 1] * d1 + r[2, 2] * d2))
        out[i, 0], out[i, 1], out[i, 2] = a0, a1, a2
