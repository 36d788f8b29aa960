"""Compiled (numba) kernel of :mod:`nerfedit_plugin.geometry.multires`: the fine surface carried by the coarse one.
It runs through :func:`~nerfedit_plugin.geometry.launch.launch`."""

from __future__ import annotations

from numba import njit, prange


@njit(cache=True, parallel=True)
def carry(points, corners, weights, table, out):
    """points (V,3), corners (V,3) int64, weights (V,3), table (C,16): per coarse vertex ``k`` its moved position
    ``y_k`` (columns 0–2), linear map ``M_k`` row-major (3–11) and rest position ``q_k`` (12–14) → out (V,3) (float32
    or float64, summed in float64): ``out_i = Σ_c w_ic (y_k + M_k (p_i − q_k))``, ``k = corners[i, c]`` (terms of
    weight 0 skipped)."""
    for i in prange(len(points)):
        p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
        a0 = a1 = a2 = 0.0
        for c in range(3):
            w = weights[i, c]
            if w == 0.0:
                continue
            t = table[corners[i, c]]
            d0, d1, d2 = p0 - t[12], p1 - t[13], p2 - t[14]
            a0 += w * (t[0] + (t[3] * d0 + t[4] * d1 + t[5] * d2))
            a1 += w * (t[1] + (t[6] * d0 + t[7] * d1 + t[8] * d2))
            a2 += w * (t[2] + (t[9] * d0 + t[10] * d1 + t[11] * d2))
        out[i, 0], out[i, 1], out[i, 2] = a0, a1, a2
